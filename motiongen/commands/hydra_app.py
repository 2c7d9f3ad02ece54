"""The `main(argv=None)` of a Hydra app: `train`, `sample`, `evaluate` and `train-body-mlp`, each
configured by motiongen/configs/<app>.yaml over the structured configs of motiongen/config.py
(docs/config.md)."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Callable

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.checks import require_output_path
from motiongen.cli import CONFIG_DIR, Interrupted, check_hydra_overrides, ending_line, user_errors_exit_2
from motiongen.config import register_configs

# What Hydra writes into a run directory before the app runs: its record of the config.
HYDRA_RECORD = ("config.yaml", "hydra.yaml", "overrides.yaml")


def hydra_command(config_name: str, task: Callable[[DictConfig, Path], object]) -> Callable[[list[str] | None], None]:
    """`main(argv=None)` for the app of configs/<config_name>.yaml: a malformed override, an
    unknown key, a value of the wrong type or a missing group option is one line and exit 2
    (`check_hydra_overrides`), then `task(cfg, run_dir)` runs under `hydra.main` with the
    composed config and Hydra's run directory, a user error again one line and exit 2, Ctrl-C
    one line and exit 130. A run that ends that way leaves no run directory behind where Hydra
    made it for this run and nothing but Hydra's own files is in it."""
    register_configs()
    # Before Hydra starts: the run dir the overrides name if it exists already (then it is never
    # removed), and its deepest folder that exists (the empty folders Hydra makes below it go
    # with a removed run dir). Hydra's own run dir may be a second later than the one named here
    # when it holds `${now:...}`: a fresh name, which the rule on its content alone then guards.
    before: dict[str, Path | None] = {"run_dir": None, "parent": None}

    @hydra.main(config_path="pkg://motiongen.configs", config_name=config_name, version_base="1.3")
    @user_errors_exit_2
    def app(cfg: DictConfig) -> None:
        hc = HydraConfig.get()
        run_dir = Path(hc.runtime.output_dir)
        try:
            task(cfg, run_dir)
        except BaseException as e:
            if isinstance(e, SystemExit) and not e.code:
                raise
            removed = _clear_failed_run(run_dir, hc, before)
            _note_in_log_files(e)                        # the log files left, if any
            if removed and type(e) is KeyboardInterrupt:
                raise Interrupted("nothing written") from None
            raise

    @user_errors_exit_2                                  # Ctrl-C while Hydra starts: one line too
    def main(argv: list[str] | None = None) -> None:
        # The program name in Hydra's usage line: the script's, or `motiongen <command>`.
        prog = sys.argv[0] if argv is None else f"motiongen {config_name.replace('_', '-')}"
        argv = sys.argv[1:] if argv is None else list(argv)
        run_dir = check_hydra_overrides(argv, config_name=config_name, config_dir=CONFIG_DIR)
        if run_dir is not None:                          # Hydra makes it first: one line, not its traceback
            require_output_path("out" if any(a.startswith("out=") for a in argv) else "hydra.run.dir", run_dir,
                                directory=True)
        before["run_dir"] = run_dir.resolve() if run_dir is not None and run_dir.exists() else None
        before["parent"] = _deepest_existing(run_dir) if run_dir is not None else None
        sys.argv = [prog, *argv]                         # hydra.main reads its overrides from sys.argv
        app()

    return main


def _clear_failed_run(run_dir: Path, hc, before: dict[str, Path | None]) -> bool:
    """After a run that was refused or interrupted: remove its run directory when it did not
    exist before the run and holds nothing but Hydra's start-up files, and the empty folders
    Hydra made on the way to it. True when it is gone."""
    if before["run_dir"] == run_dir.resolve():
        return False
    if not _remove_hydra_only_dir(run_dir, hc.output_subdir, f"{hc.job.name}.log"):
        return False
    _remove_empty_folders(run_dir.parent, before["parent"])
    return True


def _remove_hydra_only_dir(run_dir: Path, record_dir: str | None, log_name: str) -> bool:
    """Remove `run_dir` if it holds nothing but what Hydra wrote at start-up (its config record
    in `record_dir`, the job's log); True when it is gone. Files are removed by name, never a
    whole tree, so anything else in it (a resumed run's checkpoints, a user's files) stays."""
    if not run_dir.is_dir():
        return False
    record = run_dir / record_dir if record_dir else None
    ours = [run_dir / log_name] + ([record / n for n in HYDRA_RECORD] if record else [])
    for p in run_dir.iterdir():
        if p == record and p.is_dir() and all(q in ours for q in p.iterdir()):
            continue
        if p not in ours:
            return False
    _close_log_files_in(run_dir)
    try:
        for p in ours:
            p.unlink(missing_ok=True)
        if record is not None and record.is_dir():
            record.rmdir()
        run_dir.rmdir()
    except OSError:                                      # something appeared meanwhile: keep it
        return False
    return True


def _deepest_existing(path: Path) -> Path:
    """`path` or the deepest of its folders that exists."""
    path = path.resolve()
    return next(p for p in (path, *path.parents) if p.exists())


def _remove_empty_folders(folder: Path, stop: Path | None) -> None:
    """Remove `folder` and its parents below `stop` while they are empty: the folders Hydra made
    on the way to a run directory that is gone (`runs/sample/`), none that was there before."""
    d = folder.resolve()
    while stop is not None and stop in d.parents:
        try:
            d.rmdir()
        except OSError:                                  # not empty: another run's
            return
        d = d.parent


def _close_log_files_in(run_dir: Path) -> None:
    """Detach Hydra's log-file handlers that write into `run_dir`, which is about to go."""
    for h in list(logging.root.handlers):
        if isinstance(h, logging.FileHandler) and Path(h.baseFilename).resolve().parent == run_dir.resolve():
            logging.root.removeHandler(h)
            h.close()


def _note_in_log_files(e: BaseException) -> None:
    """The line a run ends with (`error: ...`, `interrupted: ...`), in the run's log file too:
    the console gets it from `user_errors_exit_2`, so only the file handlers take it here."""
    line = ending_line(e)
    if line is None:
        return
    record = logging.LogRecord("motiongen", logging.ERROR, __file__, 0, line, None, None)
    for h in logging.root.handlers:
        if isinstance(h, logging.FileHandler):
            h.handle(record)
