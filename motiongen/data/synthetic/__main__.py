"""python -m motiongen.data.synthetic out=DIR [size=default|small] [seed=0] [overwrite=false] [workers=N]"""

from __future__ import annotations

import sys
import time

from motiongen.cli import user_errors_exit_2
from motiongen.errors import ConfigError

KEYS = ("out", "size", "seed", "overwrite", "workers")


def _parse(argv: list[str]) -> dict[str, str]:
    opts = {}
    for arg in argv:
        key, eq, value = arg.partition("=")
        if not eq or key not in KEYS:
            raise ConfigError(f"expected key=value with key in {list(KEYS)}, got {arg!r}")
        opts[key] = value
    if not opts.get("out"):
        raise ConfigError("out=DIR is required (where to write the dataset)")
    return opts


def _int(opts: dict, key: str, default: int | None) -> int | None:
    if key not in opts:
        return default
    try:
        return int(opts[key])
    except ValueError:
        raise ConfigError(f"{key} must be an integer, got {opts[key]!r}") from None


def _bool(opts: dict, key: str) -> bool:
    v = opts.get(key, "false").lower()
    if v not in ("true", "false", "1", "0", "yes", "no"):
        raise ConfigError(f"{key} must be true or false, got {opts[key]!r}")
    return v in ("true", "1", "yes")


@user_errors_exit_2
def main(argv: list[str] | None = None) -> None:
    from motiongen.data.format import MotionDataset
    from motiongen.data.synthetic import generate

    opts = _parse(sys.argv[1:] if argv is None else argv)
    t0 = time.perf_counter()
    root = generate(opts["out"], size=opts.get("size", "default"), seed=_int(opts, "seed", 0),
                    overwrite=_bool(opts, "overwrite"), workers=_int(opts, "workers", None))
    ds = MotionDataset.open(root, check_values=False)
    minutes = ds.num_frames / ds.fps / 60
    print(f"synthetic dataset at {root}: {len(ds.scenes)} scenes, {len(ds.sequences)} sequences, "
          f"{ds.num_frames} frames ({minutes:.1f} min at {ds.fps:g} fps), generated in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
