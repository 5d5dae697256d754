import numpy as np
import pytest

from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.timing import StageRecord, StageTimer, frame_totals, read_records, stage_stats, summarise, write_records


def test_stage_records_frames_and_interleaving():
    t = StageTimer()
    c = t.begin("colour")
    t.add("decode", 1.0)
    t.begin("depth")
    t.add("a", 2.0)
    t.add("b", 3.0)
    t.resume(c, "colour")
    t.add("render", 4.0)
    d2 = t.begin("depth")
    assert d2 == 2  # resuming does not reuse numbers
    with t.stage("a"):
        pass
    assert t.records[-1].frame == 2 and t.records[-1].ms >= 0
    assert sorted(frame_totals(t.records, "colour")) == [5.0]
    totals = dict(zip(*np.unique([r.frame for r in t.records if r.kind == "depth"], return_counts=True)))
    assert totals == {1: 2, 2: 1}
    assert frame_totals(t.records, "depth", exclude=["a"]) == [3.0]


def test_summaries_match_numpy():
    rng = np.random.default_rng(0)
    ms = rng.gamma(2.0, 3.0, 101)
    recs = [StageRecord(i, "depth", "s", float(v)) for i, v in enumerate(ms)]
    s = summarise(recs)["s"]
    assert s["count"] == 101
    assert s["median_ms"] == pytest.approx(np.median(ms)) and s["p95_ms"] == pytest.approx(np.percentile(ms, 95))
    assert np.isnan(stage_stats([])["median_ms"])


def test_csv_round_trip_and_errors(tmp_path):
    recs = [StageRecord(0, "depth", "Point cloud to RGB-D", 1.25), StageRecord(1, "colour", "Composite", 0.5)]
    write_records(tmp_path / "t.csv", recs)
    back = read_records(tmp_path / "t.csv")
    assert [(r.frame, r.kind, r.stage) for r in back] == [(r.frame, r.kind, r.stage) for r in recs]
    np.testing.assert_allclose([r.ms for r in back], [r.ms for r in recs])
    (tmp_path / "bad.csv").write_text("frame,kind,stage,ms\n0,depth,x,1.0\n1,depth,y,nan\n")
    with pytest.raises(LogFormatError, match="bad.csv:3"):
        read_records(tmp_path / "bad.csv")
    (tmp_path / "hdr.csv").write_text("a,b\n")
    with pytest.raises(LogFormatError, match="hdr.csv:1"):
        read_records(tmp_path / "hdr.csv")
    with pytest.raises(LogFormatError, match="no such file"):
        read_records(tmp_path / "none.csv")
