"""An evaluation's report: report.json, report.md and figures (every file written to a temp
name in `out` and renamed when all are done), and TensorBoard scalars and figures.
docs/evaluation.md explains every column; `motiongen evaluate` (motiongen/commands/) runs it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from motiongen.eval.plots import plot_metric_bars, plot_scene_pairs
from motiongen.eval.protocol import Evaluation
from motiongen.staging import StagedOutputs

# (key, label, unit, arrow): arrow says which way is better; "≈ref" = closer to the reference row.
# Two tables: is it a body (one skeleton, planted feet, no skin in furniture), and does it do the task.
BODY_METRICS = [
    ("bone_cv", "bone CV", "ratio", "↓"),
    ("bone_max_dev", "bone max dev", "ratio", "↓"),
    ("slide_mps", "grounded slide", "m/s", "↓"),
    ("foot_skating", "foot skating", "ratio", "↓"),
    ("toe_height_m", "lower toe height", "m", "≈ref"),
    ("heading_deg", "walk heading off travel", "°", "↓"),
    ("knee_walk_deg", "walking knee angle", "°", "≈ref"),
    ("jerk", "mean jerk", "m/s³", "≈ref"),
    ("seam_ratio", "seam jump", "ratio", "≈ref"),
    ("penetration_frames", "scene pen. frames (joints)", "ratio", "↓"),
    ("penetration_max_m", "scene pen. max (joints)", "m", "↓"),
    ("mesh_penetration_frames", "scene pen. frames (mesh)", "ratio", "↓"),
    ("mesh_penetration_max_m", "scene pen. max (mesh)", "m", "↓"),
    ("floor_penetration_frames", "floor pen. frames", "ratio", "↓"),
]
TASK_METRICS = [
    ("goal_dist_body_m", "goal dist (hips)", "m", "↓"),
    ("goal_dist_m", "goal dist (pelvis)", "m", "↓"),
    ("success_0.2", "success@0.2 (hips)", "ratio", "↑"),
    ("success_0.5", "success@0.5 (hips)", "ratio", "↑"),
    ("traj_fail_rate", "traj fail", "ratio", "↓"),
    ("completed", "completed", "ratio", "↑"),
    ("mesh_contact_rate", "contact (mesh)", "ratio", "↑"),
    ("touched", "touched (mesh)", "ratio", "↑"),
    ("hand_object_sdist_m", "hand-object signed dist (mesh)", "m", "≈ref"),
    ("hand_inside_frames", "hand inside object (mesh)", "ratio", "↓"),
    ("contact_rate", "contact (joints)", "ratio", "↑"),
    ("object_dist_m", "hand-object dist (joints)", "m", "↓"),
    ("apd_m", "APD", "m", "↑"),
    ("pskl_gen_ref", "PSKL(gen,ref)", "nats", "↓"),
    ("pskl_ref_gen", "PSKL(ref,gen)", "nats", "↓"),
]
METRICS = BODY_METRICS + TASK_METRICS
# Rows of every table: the output, the network's joints before they were put on a body, the data.
ROWS = (("model", "model"), ("model_raw", "network joints"), ("reference", "reference"), ("mocap", "real mocap"))
DYNAMIC_ONLY = {"object_dist_m", "touched", "hand_object_sdist_m", "hand_inside_frames"}


def _clean(v):
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v) if math.isfinite(float(v)) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    return v


def build_report(ev, meta: dict) -> dict:
    """The report.json payload: meta, per setting the model and reference rows, per-pair details."""
    out = {"meta": meta, "metrics": [{"key": k, "label": lab, "unit": u, "better": a} for k, lab, u, a in METRICS],
           "notes": list(ev.notes), "wall_s": ev.wall_s, "settings": {}}
    for st in ev.settings:
        pairs = []
        for r in ev.results[st]:
            d = r.pair.describe()
            d["apd_m"] = r.apd
            d["completed"] = r.completed
            d["seconds"] = r.wall_s
            d["samples"] = [{k: v for k, v in m.items() if not k.startswith("_")} for m in r.per_sample]
            d["ablated"] = sorted(r.ablation)
            pairs.append(d)
        model = dict(ev.model.get(st, {}))
        if meta.get("goal_pinned"):
            model["goal_dist_m"] = None          # the sampler put the pelvis there: not the model's doing
        out["settings"][st] = {"model": model, "model_raw": ev.model_raw.get(st, {}),
                               "reference": ev.reference.get(st, {}), "mocap": meta.get("mocap_row") or {},
                               "ablation": ev.ablation.get(st, {}), "pairs": pairs}
    return _clean(out)


def _fmt(v, unit: str) -> str:
    if v is None:
        return "n/a"
    if unit == "ratio":
        return f"{v:.3f}"
    a = abs(v)
    return f"{v:.3g}" if a >= 100 or a < 0.01 and a > 0 else f"{v:.3f}"


def _cell(block: dict, row: str, key: str, unit: str, spread: str = "spread") -> str:
    """A table cell: the row's value, with ± its spread over checkpoints where it has one."""
    v = (block.get(row) or {}).get(key)
    sd = ((block.get(spread) or {}).get(row) or {}).get(key)
    return _fmt(v, unit) + (f" ± {_fmt(sd, unit)}" if sd else "")


def _title(m: dict) -> list[str]:
    """The heading: one checkpoint, or the checkpoints a mean is over."""
    if "ckpts" not in m:
        return [f"# Evaluation: `{m['ckpt']}` (step {m['step']})", ""]
    return [f"# Evaluation: {len(m['ckpts'])} checkpoints", "",
            "Every figure is the mean over the checkpoints ± their sample standard deviation "
            "(one training seed each): " + ", ".join(f"`{c}` (step {s})" for c, s in zip(m["ckpts"], m["ckpt_steps"]))
            + ".", ""]


def markdown(report: dict, plots: bool = True) -> str:
    """report.md's text; `plots`: whether the figures it links to were written (evaluate plots=)."""
    m = report["meta"]
    lines = [*_title(m),
             f"Dataset `{m['dataset']}`, {m.get('split', 'test')} scenes {', '.join(str(s) for s in m['scenes'])}; "
             f"k = {m['k']} samples per pair, {m['pairs']} pairs per scene and setting; "
             f"{m['sampler'].upper()}-{m['steps']}, guidance {m['guidance_scale']}, seed {m['seed']}. "
             f"Wall time {report['wall_s']:.0f} s.", "",
             "Arrows: ↓ lower is better, ↑ higher is better, ≈ref closer to the reference row is better. "
             "The reference row is the dataset's own motion in the same scenes; n/a where a metric does "
             "not apply to it (docs/evaluation.md).", ""]
    loop = (m.get("protocol") or {}).get("loop")
    if loop:
        lines += ["Sampler clean-up set for this run (the rest at the sampler's defaults): "
                  + ", ".join(f"`loop.{k}={v}`" for k, v in loop.items()) + ".", ""]
    if m.get("goal_pinned"):
        lines += ["This checkpoint pins the goal's pelvis x, z (trained before goals were predicted): "
                  "goal dist (pelvis) is n/a, the hips are the body's own.", ""]
    for st, block in report["settings"].items():
        n = block["model"].get("n_pairs", 0)
        lines += [f"## {st} setting", "",
                  f"{n} pair(s), {block['model'].get('n_samples', 0)} sample(s); reference: "
                  f"{block['reference'].get('n_sequences', 0)} sequence(s), {block['reference'].get('n_frames', 0)} frames. "
                  "Rows: the output motions; the network's own joints before they are put on one body "
                  "(what the clean-up did); the dataset's motion"
                  + ("; real mocap through our importer (`mocap=`: " + ", ".join(block["mocap"].get("files", []))
                     + ")" if block.get("mocap") else "") + ".", ""]
        if not n:
            lines += ["No pairs in this setting (see notes).", ""]
            continue
        for title, group in (("Body", BODY_METRICS), ("Task", TASK_METRICS)):
            keys = [x for x in group if st == "dynamic" or x[0] not in DYNAMIC_ONLY]
            lines.append(f"| {title} | " + " | ".join(f"{lab} {a}" + (f" [{u}]" if u != "ratio" else "")
                                                      for _, lab, u, a in keys) + " |")
            lines.append("|---|" + "---:|" * len(keys))
            for key, name in ROWS:
                row = block.get(key) or {}
                if key == "mocap" and (not row or title != "Body"):
                    continue
                lines.append(f"| {name} | " + " | ".join(_cell(block, key, k, u) for k, _, u, _ in keys) + " |")
            lines.append("")
        lines += action_table(block)
        lines += ablation_table(st, block)
        lines += [f"![{st} metrics](plots/{st}_metrics.png)", ""] if plots else []
    if report["notes"]:
        lines += ["## Notes", ""] + [f"- {x}" for x in report["notes"]] + [""]
    if plots:
        lines += ["Trajectory figures: `plots/<setting>_scene<id>.png` (map, A* path, start ●, goal ★ / "
                  "interaction ■, object ▲, the k pelvis tracks).", ""]
    return "\n".join(lines)


def action_table(block: dict) -> list[str]:
    """PSKL by action (`pskl_sets.action_figures`) as markdown lines: each action that some row
    has a figure for, the output and the network's joints against the data's chunks of the same
    action, the reference row the data's split-half value for it ([] when no action has one)."""
    stems = [k[:-len("_gen_ref")] for k in (block.get("reference") or {})
             if k.startswith("pskl_") and k.endswith("_gen_ref") and k != "pskl_gen_ref"]
    rows = (("model", "model"), ("model_raw", "network joints"), ("reference", "reference"))
    stems = [x for x in stems if any((block.get(r) or {}).get(x + "_gen_ref") is not None for r, _ in rows[:2])]
    if not stems:
        return []
    cols = [(x + d, f"{x[len('pskl_'):].replace('_', ' ')} {lab}") for x in stems
            for d, lab in (("_gen_ref", "(gen,ref)"), ("_ref_gen", "(ref,gen)"))]
    lines = ["Each action's 2 s chunks against the data's chunks of the same action (PSKL over every chunk mixes "
             "actions; docs/evaluation.md):", "",
             "| PSKL by action [nats] | " + " | ".join(f"{lab} ↓" for _, lab in cols) + " |",
             "|---|" + "---:|" * len(cols)]
    for key, name in rows:
        lines.append(f"| {name} | " + " | ".join(_cell(block, key, k, "nats") for k, _ in cols) + " |")
    return lines + [""]


def ablation_table(setting: str, block: dict) -> list[str]:
    """The ablation rows of a setting as markdown lines ([] when it has none)."""
    abl = block.get("ablation") or {}
    if not abl:
        return []
    n = (abl.get("model") or {}).get("n_pairs", 0)
    keys = [x for x in METRICS if setting == "dynamic" or x[0] not in DYNAMIC_ONLY]
    lines = [f"**Ablation** ({n} pair(s), the same pairs and noise in every row): the output, the network's own "
             "joints, and the output with one clean-up stage off (`loop.*`; docs/evaluation.md).", "",
             "| Ablation | " + " | ".join(f"{lab} {a}" + (f" [{u}]" if u != "ratio" else "") for _, lab, u, a in keys)
             + " |", "|---|" + "---:|" * len(keys)]
    for row in abl:
        name = {"model": "output", "model_raw": "network joints"}.get(row, f"without {row.replace('_', ' ')}")
        lines.append(f"| {name} | " + " | ".join(_cell({**abl, "ablation_spread": block.get("ablation_spread")},
                                                       row, k, u, "ablation_spread") for k, _, u, _ in keys) + " |")
    return lines + [""]


def log_tensorboard(run_dir, report: dict, images: dict[str, Path], step: int) -> None:
    """Scalars eval/<setting>/<model|reference>/<metric> and the figures, at the checkpoint's step."""
    import matplotlib.image as mpimg  # matplotlib's image reader: only for run_dir=
    from torch.utils.tensorboard import SummaryWriter  # TensorBoard loads its own stack: only for run_dir=

    w = SummaryWriter(log_dir=str(run_dir))
    try:
        for st, block in report["settings"].items():
            for row, _ in ROWS:
                for k, v in (block.get(row) or {}).items():
                    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
                        w.add_scalar(f"eval/{st}/{row}/{k}", v, step)
        for tag, path in images.items():
            img = mpimg.imread(str(path))                                                   # (H, W, 4) float in [0, 1]
            w.add_image(f"eval/{tag}", img[..., :3], step, dataformats="HWC")
        w.add_text("eval/report", report.get("_markdown", ""), step)
    finally:
        w.close()


def write_report(out: Path, report: dict, md: str, ev: Evaluation, title: str, plots: bool = True) -> tuple[list[Path], dict[str, Path]]:
    """report.json, report.md and (plots) the figures in `out`, staged and renamed together:
    (the files written, {TensorBoard tag: figure})."""
    out.mkdir(parents=True, exist_ok=True)
    stage = StagedOutputs(out)
    try:
        images = plot_figures(stage, out, report, ev, title) if plots else {}
        stage.tmp("report.json").write_text(json.dumps(report, indent=1, ensure_ascii=False))
        stage.tmp("report.md").write_text(md)
        return stage.commit(), images
    except BaseException:
        stage.abort()
        raise


def plot_figures(stage: StagedOutputs, out: Path, report: dict, ev: Evaluation, title: str) -> dict[str, Path]:
    """plots/<setting>_metrics.png (each row's metrics) and plots/<setting>_scene<id>.png (the
    pairs' tracks) for every setting with pairs; `title` ends each scene figure's title."""
    images: dict[str, Path] = {}
    for st in ev.settings:
        block = report["settings"][st]
        if not block["pairs"]:
            continue
        name = f"plots/{st}_metrics.png"
        plot_metric_bars(stage.tmp(name), {label: block.get(key) or {} for key, label in ROWS},
                         [x for x in METRICS if st == "dynamic" or x[0] not in DYNAMIC_ONLY],
                         title=f"{st} setting: model vs reference")
        images[f"{st}/metrics"] = out / name
        for sid in ev.contexts:
            rs = [r for r in ev.results[st] if r.pair.scene == sid]
            if rs:
                name = f"plots/{st}_scene{sid}.png"
                plot_scene_pairs(stage.tmp(name), ev.contexts[sid].fmap, rs, title=f"{st} — scene {sid} — {title}")
                images[f"{st}/scene{sid}"] = out / name
    return images


__all__ = ["METRICS", "build_report", "markdown", "log_tensorboard", "plot_figures", "write_report"]
