"""PSKL over sets of chunks by action (`motiongen.eval.pskl_sets`) and its table in the report:
chunks cut by label, a set that is the data's own half reads 0, an action with too few chunks
has no figure."""

import numpy as np

from motiongen.eval.pskl_sets import ACTION_MIN_CHUNKS, action_figures, by_action_keys, labelled_chunks
from motiongen.eval.report import action_table

N = 60


def test_a_chunk_has_an_action_when_half_its_frames_carry_it():
    m = np.random.default_rng(0).normal(size=(130, 22, 3))
    lab = np.full(130, -1)
    lab[:30], lab[60:89] = 1, 1                        # chunk 0: exactly half; chunk 1: one frame short
    onehot = np.zeros((130, 3), bool)
    onehot[lab >= 0, 1] = True
    for labels in (lab, onehot):                       # indices (generated) or one column per action (data)
        chunks = labelled_chunks([m], [labels], N, 1)
        assert len(chunks) == 1 and np.array_equal(chunks[0], m[:60])
    assert labelled_chunks([m], [lab], N, 0) == []


def test_each_action_is_compared_with_the_same_action_of_the_data():
    """The data: 4 walking sequences and 4 sitting ones (every other sequence makes a half), its
    columns in another order than the model's names. Output chunks that are the walking half the
    model is compared with read 0 there, while the halves differ; the sit has too few output
    chunks for a figure, the data's floor for it stays; an action the data lacks is left out."""
    rng = np.random.default_rng(1)
    T = N * ACTION_MIN_CHUNKS                           # 8 chunks a sequence; 2 walking sequences a half
    ref, labels = [], []
    for i in range(8):
        ref.append(rng.normal(size=(T, 22, 3)).cumsum(0))
        lab = np.zeros((T, 2), bool)
        lab[:, i % 2 if i < 4 else 1 - i % 2] = True   # columns: ["sit", "walk"]
        labels.append(lab)
    walk_seqs = [i for i in range(8) if labels[i][0, 1]]
    half_b = [ref[i] for i in walk_seqs if i % 2 == 1]
    gen = half_b + [ref[0][:N]]
    gen_labels = [np.zeros(len(g), np.int64) for g in half_b] + [np.full(N, 2)]   # model names: walk, stand, sit
    f = action_figures(gen, gen_labels, ["walk", "stand", "sit", "fly"], ref, labels, ["sit", "walk"], N, 30.0)
    assert set(f) == {"walk", "sit"}                   # "stand" and "fly": the data has none
    assert f["walk"]["chunks"] == f["walk"]["half_chunks"] >= ACTION_MIN_CHUNKS
    np.testing.assert_allclose(f["walk"]["gen"], 0.0, atol=1e-9)
    assert min(f["walk"]["floor"]) > 0.01
    assert f["sit"]["gen"] is None and f["sit"]["gen_chunks"] == 1 and f["sit"]["floor"] is not None
    keys = by_action_keys(f, "gen")
    assert keys["pskl_sit_gen_ref"] is None and keys["pskl_walk_ref_gen"] == f["walk"]["gen"][1]

    block = {"model": keys, "model_raw": keys, "reference": by_action_keys(f, "floor")}
    md = "\n".join(action_table(block))
    assert "| walk (gen,ref) ↓ | walk (ref,gen) ↓ |" in md and "sit (gen,ref)" not in md   # no row has the sit's
    assert md.count("| model |") == md.count("| reference |") == 1
    assert action_table({"model": {}, "reference": by_action_keys(f, "floor")}) == []
