"""One report over several checkpoints (`evaluate ckpt=[a,b,c]`: the same recipe trained with
different seeds): per figure the mean over checkpoints, its spread (sample standard deviation)
and each checkpoint's value. A recipe's figure is its mean; a difference between two recipes
smaller than their spreads is not one."""

from __future__ import annotations

import math

import numpy as np

from motiongen.eval.protocol import Evaluation
from motiongen.eval.report import ROWS


def _numbers(rows: list[dict]) -> dict[str, list]:
    """Per key, the values of every row (None where a row has no finite number)."""
    keys = [k for k in rows[0] if all(k in r for r in rows)]
    out = {}
    for k in keys:
        vals = [r[k] for r in rows]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) or v is None for v in vals):
            out[k] = [None if v is None or not math.isfinite(float(v)) else float(v) for v in vals]
    return out


def _stats(values: list) -> tuple[float | None, float | None]:
    """(mean, sample standard deviation) of the values given (None: missing); std None for one."""
    x = np.array([v for v in values if v is not None], np.float64)
    if not len(x):
        return None, None
    if len(x) > 1 and np.ptp(x) == 0:
        # the same value from every checkpoint (the data's row): no spread, where the mean's
        # rounding would leave 1e-17 of one that report.md prints
        return float(x[0]), 0.0
    return float(x.mean()), (float(x.std(ddof=1)) if len(x) > 1 else None)


def aggregate_reports(reports: list[dict]) -> dict:
    """The report of several checkpoints' evaluations (`build_report` dicts of the same scenes,
    settings and protocol): the first's meta with `ckpts`/`ckpt_steps`, per setting and row
    the mean of every figure, `spread` (the standard deviation) and `per_ckpt` (the values),
    and the pairs of each checkpoint under `checkpoints`."""
    first = reports[0]
    meta = {**first["meta"], "ckpt": f"{len(reports)} checkpoints",
            "ckpts": [r["meta"]["ckpt"] for r in reports], "ckpt_steps": [r["meta"]["step"] for r in reports]}
    out = {"meta": meta, "metrics": first["metrics"], "notes": sorted({n for r in reports for n in r["notes"]}),
           "wall_s": sum(r["wall_s"] for r in reports), "settings": {},
           "checkpoints": [{"ckpt": r["meta"]["ckpt"], "pairs": {st: b["pairs"] for st, b in r["settings"].items()}}
                           for r in reports]}
    for st, block in first["settings"].items():
        agg = {"pairs": block["pairs"], "spread": {}, "per_ckpt": {}, "ablation": {}, "ablation_spread": {}}
        for row, _ in ROWS:
            agg[row], agg["spread"][row], agg["per_ckpt"][row] = _row([r["settings"][st].get(row) or {} for r in reports])
        for row in block.get("ablation") or {}:
            agg["ablation"][row], agg["ablation_spread"][row], _ = _row(
                [(r["settings"][st].get("ablation") or {}).get(row) or {} for r in reports])
        out["settings"][st] = agg
    return out


def _row(rows: list[dict]) -> tuple[dict, dict, dict]:
    """One row over the checkpoints: (means, spreads, each checkpoint's values)."""
    if not any(rows):
        return {}, {}, {}
    nums = _numbers(rows)
    stats = {k: _stats(v) for k, v in nums.items()}
    return {**rows[0], **{k: m for k, (m, _) in stats.items()}}, {k: s for k, (_, s) in stats.items()}, nums


def merge_settings(parts: list[tuple[dict, Evaluation]]) -> tuple[dict, Evaluation]:
    """One checkpoint's (report, Evaluation) from its runs of one setting each (`evaluate jobs=N`),
    as one run of those settings in the order given would have made them. The Evaluation's
    scene contexts stay empty: the parts come from other processes."""
    reports, evs = [p[0] for p in parts], [p[1] for p in parts]
    settings = [st for ev in evs for st in ev.settings]
    notes = list(dict.fromkeys(n for ev in evs for n in ev.notes))
    report = {**reports[0], "meta": {**reports[0]["meta"], "settings": settings}, "notes": notes,
              "wall_s": sum(r["wall_s"] for r in reports),
              "settings": {st: block for r in reports for st, block in r["settings"].items()}}
    merged = lambda name: {st: v for ev in evs for st, v in getattr(ev, name).items()}   # noqa: E731
    ev = Evaluation(settings, merged("pairs"), merged("results"), merged("references"), merged("model"),
                    merged("reference"), merged("model_raw"), merged("ablation"), {}, notes,
                    sum(ev.wall_s for ev in evs))
    return report, ev
