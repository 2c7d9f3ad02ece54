from motiongen.staging import StagedOutputs


def test_commit_renames_everything_abort_leaves_nothing(tmp_path):
    s = StagedOutputs(tmp_path)
    s.tmp("a.json").write_text("1")
    s.tmp("plots/b.png").write_text("2")
    other = tmp_path / ".tmp-writer-chose-this.gif"          # a writer that changed the suffix
    other.write_text("3")
    s.add(other, "video.gif")
    assert sorted(p.name for p in tmp_path.iterdir()) != ["a.json", "plots", "video.gif"]
    done = s.commit()
    assert sorted(p.relative_to(tmp_path).as_posix() for p in done) == ["a.json", "plots/b.png", "video.gif"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "plots", "video.gif"]

    s2 = StagedOutputs(tmp_path / "out2")
    s2.tmp("x.npz").write_text("partial")
    s2.abort()
    assert list((tmp_path / "out2").iterdir()) == []
