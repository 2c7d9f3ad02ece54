"""PSKL between sets of 2 s chunks, at equal sizes: the reference's split halves (the metric's
floor), a model against one half, and the same by action.

The estimate's bias depends on the set sizes, so every comparison thins both sets to one size.
`evaluate`'s PSKL compares every chunk of the output with every chunk of the scenes' data,
whatever is done in them (the data sits, lies, stands and walks; a dynamic sample walks and
picks up); a mixture's spectrum is broad and can read nearer the data's than any one action
does. The figures by action compare each action's chunks with the data's chunks of the same
action, beside the data's own split-half value for it.
"""

from __future__ import annotations

import numpy as np

from motiongen import metrics as M

# An action is compared where each set has at least this many chunks of it (16 s of motion);
# fewer, and its figure is None.
ACTION_MIN_CHUNKS = 8


def _chunks(motions, n: int) -> list[np.ndarray]:
    """Non-overlapping n-frame chunks of every motion (PSKL needs one length)."""
    return [m[i:i + n] for m in motions for i in range(0, len(m) - n + 1, n)]


def even_subset(items: list, m: int) -> list:
    """m of the items, evenly spaced over the list (all of them when m >= len)."""
    if m >= len(items):
        return list(items)
    return [items[i] for i in np.linspace(0, len(items), m, endpoint=False).astype(np.int64)]


def reference_halves(ref_motions, n: int) -> tuple[list, list]:
    """The reference's n-frame chunks in two halves of equal size: the chunks of every other
    sequence (whole sequences, so no chunk has its neighbour in the other half), the larger
    half evenly thinned to the smaller one's size."""
    return _equal_size(_chunks(ref_motions[0::2], n), _chunks(ref_motions[1::2], n))


def _equal_size(a: list, b: list) -> tuple[list, list]:
    """Both lists evenly thinned to the shorter one's length."""
    m = min(len(a), len(b))
    return even_subset(a, m), even_subset(b, m)


def pskl_equal(gen, ref_half, fps: float, n: int) -> tuple[float, float, int]:
    """PSKL between the generated motions' chunks and a reference half, both thinned to the
    same number of chunks (the estimate's bias depends on the set sizes, so a model and the
    reference's own floor are compared at one size). Returns (PSKL(gen,ref), PSKL(ref,gen), chunks)."""
    g = _chunks(gen, n)
    m = min(len(g), len(ref_half))
    if not m:
        return float("nan"), float("nan"), 0
    kab, kba = M.pskl(even_subset(g, m), even_subset(ref_half, m), fps, length=n)
    return kab, kba, m


def labelled_chunks(motions, labels, n: int, action: int) -> list[np.ndarray]:
    """The n-frame chunks of motions (T_i, J, 3), cut as `_chunks` cuts them, whose frames carry
    `action` on at least half of them; labels: per motion (T_i,) int action index (-1 none) or
    (T_i, A) bool, one column per action."""
    out = []
    for m, lab in zip(motions, labels):
        lab = np.asarray(lab)
        has = lab[:, action] if lab.ndim == 2 else lab == action                              # (T_i,)
        out += [m[i:i + n] for i in range(0, len(m) - n + 1, n) if 2 * has[i:i + n].sum() >= n]
    return out


def action_halves(ref, ref_labels, n: int, action: int) -> tuple[list, list]:
    """`reference_halves` of the data's chunks with `action` (`labelled_chunks`; ref_labels
    per sequence (T_i, A) bool or (T_i,) int)."""
    return _equal_size(labelled_chunks(ref[0::2], ref_labels[0::2], n, action),
                       labelled_chunks(ref[1::2], ref_labels[1::2], n, action))


def action_key(name: str) -> str:
    """The report's key stem of an action's PSKL: "pskl_walk", "pskl_lie_down"."""
    return "pskl_" + name.replace(" ", "_")


def action_figures(gen, gen_labels, gen_names, ref, ref_labels, ref_names, n: int, fps: float) -> dict:
    """Per action of `gen_names` that the data also has: {"gen": (PSKL(gen,ref), PSKL(ref,gen))
    of the output's chunks with it against one half of the data's, both thinned to one size
    (`pskl_equal`), "floor": the data's halves against each other, "chunks": the size the
    output was compared at, "gen_chunks", "half_chunks": the chunks each half has}. A figure is
    None where its sets have fewer than ACTION_MIN_CHUNKS chunks."""
    out = {}
    for i, name in enumerate(gen_names):
        if name not in ref_names:
            continue
        g = labelled_chunks(gen, gen_labels, n, i)
        a, b = action_halves(ref, ref_labels, n, ref_names.index(name))
        x, y, m = pskl_equal(g, b, fps, n) if min(len(g), len(b)) >= ACTION_MIN_CHUNKS else (None, None, 0)
        floor = pskl_equal(a, b, fps, n)[:2] if len(b) >= ACTION_MIN_CHUNKS else None
        out[name] = {"gen": None if x is None else (x, y), "floor": floor, "chunks": m, "gen_chunks": len(g),
                     "half_chunks": len(b)}
    return out


def by_action_keys(figures: dict, which: str) -> dict:
    """`action_figures` as a report row's flat keys (key_gen_ref, key_ref_gen per action): the
    output's figures (which="gen") or the data's floor ("floor"); None where there is none."""
    out = {}
    for name, f in figures.items():
        v = f[which] or (None, None)
        out[action_key(name) + "_gen_ref"], out[action_key(name) + "_ref_gen"] = v
    return out
