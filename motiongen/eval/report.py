"""`evaluate.py`: run the protocol for a resolved config and write report.json, report.md and
figures (every file written to a temp name in `out` and renamed when all are done), and log
them to TensorBoard when `run_dir=` is given. docs/evaluation.md explains every column."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from motiongen.errors import ConfigError, DataError
from motiongen.staging import StagedOutputs

# (key, label, unit, arrow): arrow says which way is better; "≈ref" = closer to the reference row.
# Two tables: is it a body (one skeleton, planted feet, no skin in furniture), and does it do the task.
BODY_METRICS = [
    ("bone_cv", "bone CV", "ratio", "↓"),
    ("bone_max_dev", "bone max dev", "ratio", "↓"),
    ("slide_mps", "grounded slide", "m/s", "↓"),
    ("foot_skating", "foot skating", "ratio", "↓"),
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
    ("contact_rate", "contact rate", "ratio", "↑"),
    ("object_dist_m", "hand-object dist", "m", "↓"),
    ("apd_m", "APD", "m", "↑"),
    ("pskl_gen_ref", "PSKL(gen,ref)", "nats", "↓"),
    ("pskl_ref_gen", "PSKL(ref,gen)", "nats", "↓"),
]
METRICS = BODY_METRICS + TASK_METRICS
# Rows of every table: the output, the network's joints before they were put on a body, the data.
ROWS = (("model", "model"), ("model_raw", "network joints"), ("reference", "reference"), ("mocap", "real mocap"))
DYNAMIC_ONLY = {"object_dist_m"}


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
            pairs.append(d)
        model = dict(ev.model.get(st, {}))
        if meta.get("goal_pinned"):
            model["goal_dist_m"] = None          # the sampler put the pelvis there: not the model's doing
        out["settings"][st] = {"model": model, "model_raw": ev.model_raw.get(st, {}),
                               "reference": ev.reference.get(st, {}), "mocap": meta.get("mocap_row") or {},
                               "pairs": pairs}
    return _clean(out)


def _fmt(v, unit: str) -> str:
    if v is None:
        return "n/a"
    if unit == "ratio":
        return f"{v:.3f}"
    a = abs(v)
    return f"{v:.3g}" if a >= 100 or a < 0.01 and a > 0 else f"{v:.3f}"


def markdown(report: dict) -> str:
    m = report["meta"]
    lines = [f"# Evaluation: `{m['ckpt']}` (step {m['step']})", "",
             f"Dataset `{m['dataset']}`, test scenes {', '.join(str(s) for s in m['scenes'])}; "
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
                lines.append(f"| {name} | " + " | ".join(_fmt(row.get(k), u) for k, _, u, _ in keys) + " |")
            lines.append("")
        lines += [f"![{st} metrics](plots/{st}_metrics.png)", ""]
    if report["notes"]:
        lines += ["## Notes", ""] + [f"- {x}" for x in report["notes"]] + [""]
    lines += ["Trajectory figures: `plots/<setting>_scene<id>.png` (map, A* path, start ●, goal ★ / "
              "interaction ■, object ▲, the k pelvis tracks).", ""]
    return "\n".join(lines)


def log_tensorboard(run_dir, report: dict, images: dict[str, Path], step: int) -> None:
    """Scalars eval/<setting>/<model|reference>/<metric> and the figures, at the checkpoint's step."""
    import matplotlib.image as mpimg
    from torch.utils.tensorboard import SummaryWriter

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


def _dataset_config(cfg, ckpt_config):
    from omegaconf import OmegaConf

    from motiongen.importers.sources import DataConfig

    node = cfg.get("data") or (ckpt_config.get("data") if ckpt_config is not None else None)
    if node is None:
        return DataConfig()
    d = OmegaConf.to_container(node, resolve=True) if not isinstance(node, dict) else dict(node)
    fields = DataConfig.__dataclass_fields__
    return DataConfig(**{k: v for k, v in d.items() if k in fields})


# evaluate.py's loop keys: the sampler's clean-up switches and their types.
LOOP_KEYS = {"project": bool, "foot_lock": bool, "pin_goal": bool, "smooth": float, "seam_blend": float,
             "solve_smoothness": float}


def loop_overrides(lc) -> dict:
    """LoopConfig fields the user set (non-null `loop.*` keys), checked and typed."""
    from omegaconf import OmegaConf

    out = {}
    for key, value in (OmegaConf.to_container(lc) if lc is not None else {}).items():
        if value is None:
            continue
        kind = LOOP_KEYS.get(key)
        if kind is None:
            raise ConfigError(f"loop.{key}: not a clean-up key evaluate.py takes ({', '.join(LOOP_KEYS)})")
        if kind is bool and not isinstance(value, bool) or kind is float and (
                isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0):
            want = "true or false" if kind is bool else "a number >= 0"
            raise ConfigError(f"loop.{key}: expected {want}, got {value!r}")
        out[key] = kind(value)
    return out


def run(cfg, default_out: Path) -> dict:
    """The whole `evaluate.py` run for a resolved config. Returns the report dict."""
    import torch
    from omegaconf import OmegaConf

    from motiongen.eval.pairs import SETTINGS, ProtocolConfig
    from motiongen.eval.protocol import evaluate
    from motiongen.sampling import SamplerSettings

    if not cfg.get("ckpt"):
        raise ConfigError("ckpt=PATH is required (a checkpoint written by train.py)")
    ckpt = Path(str(cfg.ckpt))
    if not ckpt.is_file():
        raise DataError(ckpt, None, "checkpoint file does not exist")
    settings = cfg.get("settings")
    settings = [settings] if isinstance(settings, str) else list(OmegaConf.to_container(settings) if settings is not None else SETTINGS)
    bad = [s for s in settings if s not in SETTINGS]
    if bad or not settings:
        raise ConfigError(f"settings: expected a non-empty subset of {list(SETTINGS)}, got {settings}")
    sampler = SamplerSettings(str(cfg.sampler), int(cfg.steps), float(cfg.get("eta", 0.0)), float(cfg.guidance_scale))
    if sampler.sampler not in ("ddpm", "ddim"):
        raise ConfigError(f"sampler: expected ddpm or ddim, got {sampler.sampler!r}")
    if sampler.steps < 1:
        raise ConfigError(f"steps must be >= 1, got {sampler.steps}")
    k, npairs = int(cfg.k), int(cfg.pairs)
    if k < 1 or npairs < 1:
        raise ConfigError(f"k and pairs must be >= 1, got k={k}, pairs={npairs}")
    threads = int(cfg.get("threads") or 0)
    if threads > 0:
        torch.set_num_threads(threads)
    device = str(cfg.device)
    from motiongen.loading.build import load_model

    loaded = load_model(ckpt, device, precision=str(cfg.get("precision") or "auto"))

    from motiongen.importers.sources import open_dataset

    dcfg = _dataset_config(cfg, loaded.config)
    ds = open_dataset(dcfg, verbose=True)
    test = [s for s in ds.splits.get("test", []) if s in ds.scenes]
    if not test:
        raise ConfigError(f"dataset {ds.root} has no test scenes (splits: "
                          f"{ {k: len(v) for k, v in ds.splits.items()} }); set data.splits")
    scenes = cfg.get("scenes")
    if scenes is not None:
        scenes = [scenes] if isinstance(scenes, (int, str)) else list(OmegaConf.to_container(scenes))
        try:
            scenes = [int(s) for s in scenes]
        except (TypeError, ValueError):
            raise ConfigError(f"scenes: expected a list of scene ids, got {scenes!r}") from None
        unknown = [s for s in scenes if s not in test]
        if unknown or not scenes:
            raise ConfigError(f"scenes: {unknown or scenes} not among the test scenes of {ds.root} "
                              f"({', '.join(str(s) for s in test)})")
    else:
        scenes = test
    if set(loaded.joint_set.names) != set(ds.joint_set.names):
        raise ConfigError(f"the checkpoint's joints ({len(loaded.joint_set.names)}) differ from the dataset's "
                          f"({len(ds.joint_set.names)}): evaluate on the data it was trained on")

    pc = ProtocolConfig(k=k, pairs=npairs, interaction_pairs=int(cfg.interaction_pairs),
                        static_actions=tuple(OmegaConf.to_container(cfg.static_actions)),
                        dynamic_action=str(cfg.dynamic_action), action_seconds=None if cfg.get("action_seconds") is None else float(cfg.action_seconds),
                        min_distance=float(cfg.min_distance), body_radius=float(cfg.body_radius),
                        subgoal_spacing=float(cfg.subgoal_spacing), max_episodes=int(cfg.max_episodes),
                        seed=int(cfg.seed), pskl_frames=int(cfg.pskl_frames), loop=loop_overrides(cfg.get("loop")))
    progress = bool(cfg.get("progress", True))
    from motiongen.body.model import load_body_model

    ev = evaluate(loaded, ds, scenes, pc, settings, sampler, progress=progress, log=lambda m: print(m, flush=True),
                  body_model=load_body_model(cfg.get("body_model")))

    meta = {"ckpt": str(ckpt), "step": loaded.step, "dataset": str(ds.root), "scenes": scenes, "k": k,
            "pairs": npairs, "sampler": sampler.sampler, "steps": sampler.steps, "eta": sampler.eta,
            "guidance_scale": sampler.guidance_scale, "seed": int(cfg.seed), "settings": settings,
            "protocol": {k_: (list(v) if isinstance(v, tuple) else v) for k_, v in pc.__dict__.items()},
            "device": device, "precision": loaded.precision, "torch_threads": torch.get_num_threads(), "goal_pinned": not loaded.predict_goal}
    if cfg.get("mocap"):
        from motiongen.eval.mocap import mocap_body_metrics

        m = cfg.mocap
        meta["mocap_row"] = mocap_body_metrics([m] if isinstance(m, str) else list(OmegaConf.to_container(m)), ds.fps)
    report = build_report(ev, meta)
    report["meta"].pop("mocap_row", None)
    md = markdown(report)

    out = Path(cfg.out) if cfg.get("out") else Path(default_out)
    out.mkdir(parents=True, exist_ok=True)
    stage = StagedOutputs(out)
    images: dict[str, Path] = {}
    try:
        if bool(cfg.get("plots", True)):
            from motiongen.eval.plots import plot_metric_bars, plot_scene_pairs

            spec = [(k_, lab, u, a) for k_, lab, u, a in METRICS]
            for st in settings:
                block = report["settings"][st]
                if not block["pairs"]:
                    continue
                name = f"plots/{st}_metrics.png"
                plot_metric_bars(stage.tmp(name), {label: block.get(key) or {} for key, label in ROWS},
                                 [x for x in spec if st == "dynamic" or x[0] not in DYNAMIC_ONLY],
                                 title=f"{st} setting: model vs reference")
                images[f"{st}/metrics"] = out / name
                for sid in scenes:
                    rs = [r for r in ev.results[st] if r.pair.scene == sid]
                    if rs:
                        name = f"plots/{st}_scene{sid}.png"
                        plot_scene_pairs(stage.tmp(name), ev.contexts[sid].fmap, rs,
                                         title=f"{st} — scene {sid} — {ckpt.name} step {loaded.step}")
                        images[f"{st}/scene{sid}"] = out / name
        stage.tmp("report.json").write_text(json.dumps(report, indent=1, ensure_ascii=False))
        stage.tmp("report.md").write_text(md)
        written = stage.commit()
    except BaseException:
        stage.abort()
        raise
    if cfg.get("run_dir"):
        report["_markdown"] = md
        log_tensorboard(Path(str(cfg.run_dir)), report, images, loaded.step)
        report.pop("_markdown")
    print(md, flush=True)
    print(f"wrote {len(written)} files to {out} (report.json, report.md, plots/)" +
          (f"; logged to TensorBoard in {cfg.run_dir}" if cfg.get("run_dir") else ""), flush=True)
    return report


__all__ = ["METRICS", "build_report", "markdown", "log_tensorboard", "loop_overrides", "run"]
