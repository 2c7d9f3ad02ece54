"""Each figure of one evaluate report against another's (not a timed test).

    python benchmarks/report_ratio.py BASE/report.json OTHER/report.json [tolerance=0.10] [rows=model,model_raw]

For every setting and row (the output `model`, the network's own joints `model_raw`), the
figures issue 27 holds a distilled student to beside its teacher (body, goals, contact,
PSKL): both values and OTHER's relative change from BASE; a change worse than `tolerance` in
the figure's bad direction is marked `!`. A figure near zero in BASE (below `FLOOR`) is compared
as a difference, not a ratio (0.001 against 0.002 is not a doubling), and marked once OTHER's
is not near zero.
"""

from __future__ import annotations

import json
from pathlib import Path

from motiongen.cli import parse_key_values, tool_main
from motiongen.errors import ConfigError, DataError

# (key, label, better): better "low", "high" or "near" (closer to the data's value is better,
# read as: any change beyond the tolerance is marked).
FIGURES = [("slide_mps", "grounded slide", "low"), ("foot_skating", "foot skating", "low"),
           ("toe_height_m", "lower toe height", "near"), ("heading_deg", "heading off travel", "low"),
           ("knee_walk_deg", "walking knee", "near"), ("jerk", "mean jerk", "near"),
           ("mesh_penetration_frames", "scene pen. frames (mesh)", "low"), ("bone_cv", "bone CV", "low"),
           ("goal_dist_body_m", "goal dist (hips)", "low"), ("success_0.2", "success@0.2", "high"),
           ("mesh_contact_rate", "contact (mesh)", "high"), ("hand_inside_frames", "hand inside", "low"),
           ("pskl_gen_ref", "PSKL(gen,ref)", "low"), ("pskl_ref_gen", "PSKL(ref,gen)", "low")]
FLOOR = 0.002


def _load(path: str) -> dict:
    p = Path(path)
    try:
        return json.loads(p.read_text())["settings"]
    except (OSError, ValueError, KeyError) as e:
        raise DataError(p, "settings", f"not an evaluate report.json ({type(e).__name__})") from None


def _change(base: float, other: float, better: str, tol: float) -> tuple[str, bool]:
    """The relative change (or the difference where base is near zero) and whether it is worse
    than tol in the figure's bad direction."""
    if abs(base) >= FLOOR:
        rel = other / base - 1
        text, worse = f"{rel:+.0%}", {"low": rel > tol, "high": rel < -tol, "near": abs(rel) > tol}[better]
    else:                                            # both near zero: worse only once it leaves the floor
        text, worse = f"{other - base:+.3f}", better != "high" and abs(other) >= FLOOR
    return text, worse


SPEC = {"tolerance": (float, 0.10), "rows": (list, ["model", "model_raw"])}
USAGE = __doc__.splitlines()[2].strip()


def run(argv: list[str]) -> None:
    files = [a for a in argv if "=" not in a and not a.startswith("-")]
    if len(files) != 2:
        raise ConfigError("usage: " + USAGE)
    opts = parse_key_values([a for a in argv if a not in files], SPEC, usage=USAGE)
    tol, rows = opts["tolerance"], opts["rows"]
    base, other = _load(files[0]), _load(files[1])
    print(f"{files[1]} against {files[0]} (tolerance {tol:.0%}; ! = worse by more)")
    for setting in base:
        if setting not in other:
            continue
        for row in rows:
            b, o = base[setting].get(row) or {}, other[setting].get(row) or {}
            print(f"\n{setting}, {row}")
            for key, label, better in FIGURES:
                if b.get(key) is None or o.get(key) is None:
                    continue
                text, worse = _change(float(b[key]), float(o[key]), better, tol)
                print(f"  {label:26s} {b[key]:9.4f} {o[key]:9.4f}  {text:>7s} {'!' if worse else ''}")


if __name__ == "__main__":
    tool_main(run)()                     # a bad argument: one line, exit 2
