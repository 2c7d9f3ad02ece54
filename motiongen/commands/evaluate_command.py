"""`motiongen evaluate` (evaluate.py): the static/dynamic protocol (TRUMANS supplement A.1) on
the test (or, `split=val`, validation) scenes of the checkpoint's dataset, with the dataset's own motion as a reference row,
reported as report.json, report.md and plots/ in `out` and, with `run_dir=`, in TensorBoard.
The keys: EvaluateConfig (motiongen/eval/evaluate_config.py) through configs/evaluate.yaml;
docs/evaluation.md explains every column."""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from motiongen.body.model import load_body_model
from motiongen.commands.hydra_app import hydra_command
from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError
from motiongen.eval.evaluate_config import (EVALUATE_STEPS, EvaluateConfig, dataset_config, mocap_paths,
                                            protocol_config)
from motiongen.eval.mocap import mocap_body_metrics
from motiongen.eval.pairs import SETTINGS
from motiongen.eval.protocol import Evaluation, evaluate
from motiongen.eval.report import build_report, log_tensorboard, markdown, write_report
from motiongen.eval.scene_context import SceneContext
from motiongen.eval.seeds import aggregate_reports, merge_settings
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import LoadedModel
from motiongen.loading.keys import checkpoint_paths, load_checkpoint_model
from motiongen.output_lock import OutputLock, claim_run_dir, refuse_output_over_input
from motiongen.sampling.settings import SamplerSettings, resolve_sampler
from motiongen.staging import record_outputs


def run(cfg: EvaluateConfig, default_out: Path) -> dict:
    """The whole `evaluate` run. Returns the report dict."""
    ckpts = checkpoint_paths(cfg.ckpt)
    settings = chosen_settings(cfg.settings)
    # One live run per directory; without out= each run gets a directory of its own.
    with OutputLock(cfg.out, "evaluate") if cfg.out else claim_run_dir(default_out, "evaluate") as lock:
        return evaluate_and_write(cfg, lock.dir, ckpts, settings)


@dataclass
class Prepared:
    """A checkpoint ready to evaluate: its keys, model, dataset and scenes."""

    cfg: EvaluateConfig
    ckpt: Path
    loaded: LoadedModel
    ds: MotionDataset
    scenes: list[int]


def evaluate_and_write(cfg: EvaluateConfig, out: Path, ckpts: list[Path], settings: list[str]) -> dict:
    """The evaluation of every checkpoint (one report; over several, the mean and spread of each
    figure) in `out`, replacing the report a previous run wrote there. Every checkpoint is
    loaded and checked before the first is evaluated."""
    mocap = mocap_paths(cfg.mocap)
    runs = [prepare(dataclasses.replace(cfg, ckpt=str(c)), c, out, mocap) for c in ckpts]
    roots = {str(r.ds.root) for r in runs}
    if len(roots) > 1:
        raise ConfigError(f"ckpt: the checkpoints were trained on different datasets ({', '.join(sorted(roots))}); "
                          "a mean over seeds needs one dataset (give data= to evaluate them all on one)")
    mocap_row = mocap_body_metrics(mocap, runs[0].ds.fps) if mocap else None
    t0 = time.perf_counter()
    done = evaluate_all(runs, settings, mocap_row, cfg.jobs, out)
    report = done[0][0] if len(done) == 1 else aggregate_reports([rep for rep, _ in done])
    if cfg.jobs > 1:
        # The parts ran side by side: the report's wall time is the run's, not their sum.
        report["wall_s"], report["meta"]["jobs"] = time.perf_counter() - t0, cfg.jobs
    md = markdown(report, cfg.plots)
    first = runs[0]
    title = f"{first.ckpt.name} step {first.loaded.step}" + (f" (1 of {len(runs)} checkpoints)" if len(runs) > 1 else "")
    written, images = write_report(out, report, md, done[0][1], title, cfg.plots)
    record_outputs(out, "evaluate", written, keep=[*ckpts, *mocap])   # the previous run's extra plots go
    if cfg.run_dir:
        log_tensorboard(Path(cfg.run_dir), {**report, "_markdown": md}, images, first.loaded.step)
    print(md, flush=True)
    print(f"wrote {len(written)} files to {out} (report.json, report.md{', plots/' if cfg.plots else ''})" +
          (f"; logged to TensorBoard in {cfg.run_dir}" if cfg.run_dir else ""), flush=True)
    return report


def prepare(cfg: EvaluateConfig, ckpt: Path, out: Path, mocap: list) -> Prepared:
    """Load one checkpoint and its dataset, and check them against the keys and `out`."""
    loaded = load_checkpoint_model(cfg)
    resolve_sampler(SamplerSettings.of(cfg), loaded, EVALUATE_STEPS)   # a student asked for other steps: refused now
    ds = open_dataset(dataset_config(cfg.data, loaded.config), verbose=True)
    for name in ("report.json", "report.md", "plots"):     # the report never goes over what the run reads
        refuse_output_over_input(out / name, [ckpt, ds.root, *mocap], "out")
    scenes = chosen_scenes(cfg.scenes, ds, cfg.split)
    if set(loaded.joint_set.names) != set(ds.joint_set.names):
        raise ConfigError(f"the checkpoint's joints ({len(loaded.joint_set.names)}) differ from the dataset's "
                          f"({len(ds.joint_set.names)}): evaluate on the data it was trained on")
    return Prepared(cfg, ckpt, loaded, ds, scenes)


def evaluate_one(p: Prepared, settings: list[str], mocap_row: dict | None):
    """One checkpoint's evaluation: (its report dict, the Evaluation)."""
    cfg, loaded = p.cfg, p.loaded
    protocol, sampler = protocol_config(cfg), resolve_sampler(SamplerSettings.of(cfg), loaded, EVALUATE_STEPS)
    print(f"evaluating {p.ckpt} (step {loaded.step})", flush=True)
    ev = evaluate(loaded, p.ds, p.scenes, protocol, settings, sampler, progress=cfg.progress,
                  log=lambda m: print(m, flush=True), body_model=load_body_model(cfg.body_model))
    meta = {"ckpt": str(p.ckpt), "step": loaded.step, "dataset": str(p.ds.root), "split": cfg.split,
            "scenes": p.scenes, "k": cfg.k, "pairs": cfg.pairs, "sampler": sampler.sampler, "steps": sampler.steps,
            "eta": sampler.eta, "guidance_scale": sampler.guidance_scale, "seed": cfg.seed, "settings": settings,
            "protocol": {k: (list(v) if isinstance(v, tuple) else v) for k, v in protocol.__dict__.items()},
            "device": cfg.device, "precision": loaded.precision, "torch_threads": torch.get_num_threads(),
            "goal_pinned": not loaded.predict_goal}
    if mocap_row is not None:
        meta["mocap_row"] = mocap_row
    report = build_report(ev, meta)
    report["meta"].pop("mocap_row", None)
    return report, ev


def evaluate_all(runs: list[Prepared], settings: list[str], mocap_row: dict | None, jobs: int,
                 out: Path) -> list[tuple[dict, Evaluation]]:
    """Every checkpoint's (report, Evaluation): in this process (jobs 1), or each (checkpoint,
    setting) in a worker process, `jobs` at a time, merged per checkpoint (out: the report's
    directory, which the workers check against their inputs as `prepare` does)."""
    if jobs == 1:
        return [evaluate_one(r, settings, mocap_row) for r in runs]
    units = [(i, st) for i in range(len(runs)) for st in settings]
    threads = runs[0].cfg.threads or max(1, (os.cpu_count() or 1) // jobs)
    # spawn, not fork: a forked child would inherit torch's thread pools and OpenMP state.
    pool = ProcessPoolExecutor(min(jobs, len(units)), mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = [pool.submit(_evaluate_part, runs[i].cfg, runs[i].ckpt, out, st, mocap_row, threads) for i, st in units]
        parts = [f.result() for f in futures]
    finally:
        pool.shutdown(cancel_futures=True)     # a part that failed: the queued ones are not started
    merged = []
    for i, run in enumerate(runs):
        report, ev = merge_settings([part for part, (j, _) in zip(parts, units) if j == i])
        ev.contexts = {sid: SceneContext(run.ds, sid, run.cfg.body_radius) for sid in run.scenes}   # for the plots
        merged.append((report, ev))
    return merged


def _evaluate_part(cfg: EvaluateConfig, ckpt: Path, out: Path, setting: str, mocap_row: dict | None, threads: int):
    """One checkpoint's evaluation in one setting, in a worker process: (its report, its
    Evaluation without the scene contexts, which hold the dataset)."""
    cfg = dataclasses.replace(cfg, threads=threads, progress=False)
    torch.set_num_threads(threads)
    report, ev = evaluate_one(prepare(cfg, ckpt, out, mocap_paths(cfg.mocap)), [setting], mocap_row)
    ev.contexts = {}
    return report, ev


def chosen_settings(value) -> list[str]:
    """The `settings` key: one setting or a list of them, all of SETTINGS when null."""
    settings = [value] if isinstance(value, str) else list(value if value is not None else SETTINGS)
    bad = [s for s in settings if s not in SETTINGS]
    if bad or not settings:
        raise ConfigError(f"settings: expected a non-empty subset of {list(SETTINGS)}, got {settings}")
    return settings


def chosen_scenes(value, ds: MotionDataset, split: str = "test") -> list[int]:
    """The `scenes` key: ids among the dataset's scenes of `split` (val or test), all of them
    when null."""
    ids = [s for s in ds.splits.get(split, []) if s in ds.scenes]
    if not ids:
        raise ConfigError(f"dataset {ds.root} has no {split} scenes (splits: "
                          f"{ {k: len(v) for k, v in ds.splits.items()} }); set data.splits")
    if value is None:
        return ids
    scenes = [value] if isinstance(value, (int, str)) else list(value)
    try:
        scenes = [int(s) for s in scenes]
    except (TypeError, ValueError):
        raise ConfigError(f"scenes: expected a list of scene ids, got {scenes!r}") from None
    unknown = [s for s in scenes if s not in ids]
    if unknown or not scenes:
        raise ConfigError(f"scenes: {unknown or scenes} not among the {split} scenes of {ds.root} "
                          f"({', '.join(str(s) for s in ids)})")
    return scenes


def _app(cfg: DictConfig, run_dir: Path) -> None:
    run(OmegaConf.to_object(cfg), run_dir)


main = hydra_command("evaluate", _app)


if __name__ == "__main__":
    main()
