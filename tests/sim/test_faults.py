"""The faulty device (sim/faults.py, Simulator(faults=...)) and the pipeline's survival of each fault.

Each fault is checked twice: on the simulated stream, against the fault-free stream of the same seed
(what changed, and nothing else), and through the pipeline, whose skip counts are compared with
counts taken from the fault record, not from the pipeline's own logic."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError
from rgbd_envmap.pipeline import DepthStep, Pipeline, PipelineConfig, PoseCheckConfig, RenderConfig
from rgbd_envmap.pipeline.capture import CaptureConfig
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.faults import FaultConfig, PoseJump, Span, TrackingLoss, random_spans
from sim.limits import MAX_DURATION_S, check_duration
from sim.session import Simulator
from sim.trajectory import load_trajectory

DURATION = 2.0
ORIGIN = np.array([0.0, 0.0, 0.8])
CFG = PipelineConfig(capture=CaptureConfig(height=125, width=250), render=RenderConfig(enabled=False))
DEVICE = TangoDeviceConfig(colour=ColourCameraConfig(width=320, height=180))


def _sim(office, faults=None, events=None):
    return Simulator(office, load_trajectory("orbit"), DEVICE, seed=2, faults=faults,
                     on_fault=None if events is None else events.append)


@pytest.fixture(scope="module")
def clean(office):
    return list(_sim(office).run(DURATION))


def _key(sp):
    return sp.packet.kind, sp.packet.timestamp_ns


def _faulty(office, faults):
    events: list[dict] = []
    return list(_sim(office, faults, events).run(DURATION)), events


def _pipeline(packets, **config):
    pipe = Pipeline(replace(CFG, **config), DEVICE.calibration(), ORIGIN)
    steps = [r for sp in packets for r in pipe.feed(sp.packet)]
    pipe.finish()
    em = pipe.capture.em
    assert np.isfinite(em.radiance[em.valid]).all() and np.isfinite(em.depth_m[em.valid]).all()
    assert np.isfinite(pipe.coeffs).all()
    return pipe, steps


def _with(events, name, kind=None):
    return [e for e in events if name in e["faults"] and (kind is None or e["kind"] == kind)]


# --- configuration ------------------------------------------------------------------------------------

def test_everything_off_by_default_and_no_fault_is_the_fault_free_stream(office, clean):
    assert not FaultConfig().enabled and not FaultConfig(reorder_window=1).enabled
    assert _sim(office, FaultConfig(seed=9)).faults is None
    got = list(_sim(office, FaultConfig(seed=9)).run(DURATION))
    assert [sp.packet for sp in got] == [sp.packet for sp in clean]


@pytest.mark.parametrize("kwargs, error", [
    ({"depth_dropout_p": 1.5}, RangeError),
    ({"colour_dropout_p": -0.1}, RangeError),
    ({"frozen_colour_p": float("nan")}, RangeError),
    ({"depth_dropout_bursts": (1.0, 2.0)}, DTypeError),
    ({"tracking_loss": (Span(1.0, 1.0),)}, DTypeError),
    ({"timestamp_jitter_ms": -1.0}, RangeError),
    ({"reorder_window": 2.5}, DTypeError),
    ({"seed": -1}, RangeError),
])
def test_bad_fault_settings_are_refused(kwargs, error):
    with pytest.raises(error):
        FaultConfig(**kwargs)


@pytest.mark.parametrize("make", [
    lambda: Span(-1.0, 1.0), lambda: Span(1.0, 0.0), lambda: Span(1.0, float("nan")),
    lambda: TrackingLoss(1.0, 1.0, "lost"), lambda: PoseJump(1.0, 1.0, (0.1, 0.0)),
    lambda: PoseJump(1.0, 1.0, (0.1, 0.0, float("inf"))), lambda: PoseJump(1.0, 1.0, yaw_deg=200.0),
])
def test_bad_spans_are_refused(make):
    with pytest.raises(InvalidInputError):
        make()


def test_jitter_must_keep_each_stream_in_order(office):
    with pytest.raises(RangeError, match="timestamp_jitter_ms"):
        _sim(office, FaultConfig(timestamp_jitter_ms=8.5))  # a quarter of a 33.3 ms colour period is 8.33 ms


def test_spans_contain_their_start_not_their_end_and_inf_runs_on():
    s = Span(1.0, 0.5)
    assert s.contains(1.0) and s.contains(1.4999) and not s.contains(1.5) and not s.contains(0.999)
    assert Span(2.0, math.inf).contains(1e6)


def test_random_spans_are_seeded_disjoint_and_inside():
    a = random_spans(3, 600.0, 30.0, 1.5, after_s=60.0)
    assert a == random_spans(3, 600.0, 30.0, 1.5, after_s=60.0) and a != random_spans(4, 600.0, 30.0, 1.5, after_s=60.0)
    assert 8 <= len(a) <= 30  # about (600 - 60) / 31.5 = 17
    assert all(60.0 < s.start_s < 600.0 for s in a)
    assert all(a[i].start_s + a[i].duration_s <= a[i + 1].start_s for i in range(len(a) - 1))


# --- durations ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan, 0.0, -1.0, 1e7, MAX_DURATION_S * 1.0001])
def test_duration_is_bounded_before_anything_is_allocated(office, bad):
    with pytest.raises(RangeError, match="duration"):
        check_duration(bad)
    with pytest.raises(RangeError, match="duration"):
        _sim(office).counts(bad)
    with pytest.raises(RangeError, match="duration"):
        next(_sim(office).run(bad))


def test_schedule_is_lazy_and_counts_agree(office):
    sim = _sim(office)
    assert sim.counts(MAX_DURATION_S) == {"depth": 432_000, "colour": 2_592_000}
    it = sim.iter_schedule(MAX_DURATION_S)  # a day's schedule, without building it
    first = [next(it) for _ in range(8)]
    assert first == sim.schedule(0.3)[:8]
    assert sim.counts(2.0) == {"depth": 10, "colour": 60} and len(sim.schedule(2.0)) == 70


def test_cli_refuses_unbounded_durations_in_one_line(tmp_path, capsys):
    from apps.cli import main

    for text in ("inf", "1e7", "nan", "-2"):
        assert main(["simulate", "--duration", text, "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--duration" in err[0] and "86400" in err[0]
    assert not any(tmp_path.iterdir())  # refused before anything is written


# --- each fault on the stream and through the pipeline --------------------------------------------------

def test_depth_dropout_empties_exactly_the_chosen_clouds(office, clean):
    faults = FaultConfig(seed=1, depth_dropout_p=0.3, depth_dropout_bursts=(Span(1.0, 0.3),))
    got, events = _faulty(office, faults)
    assert [_key(s) for s in got] == [_key(s) for s in clean]
    dropped = {e["timestamp_ns"] for e in _with(events, "depth_dropout")}
    assert {1_000_000_000 + 1_000_000_000, 1_000_000_000 + 1_200_000_000} <= dropped  # the burst's two packets
    for a, b in zip(got, clean):
        if a.packet.kind == "depth" and a.packet.timestamp_ns in dropped:
            assert len(a.packet.points_m) == 0 and a.faults == ("depth_dropout",)
            assert a.packet.T_world_from_depth == b.packet.T_world_from_depth
        else:
            assert a.packet == b.packet and a.faults == ()
    pipe, _ = _pipeline(got)
    assert pipe.skipped == {"depth_no_points": len(dropped)}
    assert pipe.depth_steps == 10 - len(dropped)


def test_colour_dropout_withholds_frames_and_the_gaps_are_counted(office, clean):
    faults = FaultConfig(seed=1, colour_dropout_p=0.2, colour_dropout_bursts=(Span(0.5, 0.25),))
    got, events = _faulty(office, faults)
    lost = {e["timestamp_ns"] for e in _with(events, "colour_dropout")}
    assert len(lost) >= 8  # the burst's 8 frames (0.5 … 0.733 s) and some at random
    assert [s.packet for s in got] == [s.packet for s in clean if not (s.packet.kind == "colour" and s.packet.timestamp_ns in lost)]
    depth_times = {s.packet.timestamp_ns for s in clean if s.packet.kind == "depth"}
    pipe, _ = _pipeline(got)
    # A missing last frame is not a gap anyone can see; every other lost frame is.
    last = max(s.packet.timestamp_ns for s in clean if s.packet.kind == "colour")
    assert pipe.skipped.get("colour_missing", 0) == len(lost - {last})
    # A depth packet whose same-time frame is lost has none within 20 ms (the next is 33 ms away):
    # it pairs with the nearest delivered frame within 50 ms (the earlier one on a tie), if any.
    delivered = sorted(s.packet.timestamp_ns for s in got if s.packet.kind == "colour")
    orphans = sorted(lost & depth_times)
    want = {}
    for t in orphans:
        near = [c for c in delivered if abs(c - t) <= 50_000_000]
        if near:
            want[t] = min(near, key=lambda c: (abs(c - t), c))
    assert 0 < len(want) < len(orphans)  # the burst leaves one depth packet (0.6 s) with no frame within 50 ms
    assert pipe.late_pairs == len(want)
    assert pipe.skipped.get("depth_no_colour", 0) == len(orphans) - len(want) == pipe.dropped_depth
    steps = {r.timestamp_ns: r.colour_timestamp_ns for r in _pipeline(got)[1] if isinstance(r, DepthStep)}
    assert {t: steps[t] for t in want} == want
    assert pipe.depth_steps == 10 - (len(orphans) - len(want))
    # Without the fallback, every such depth packet is dropped (the pipeline before the fallback).
    strict = Pipeline(replace(CFG, colour_fallback_lag_ms=None), DEVICE.calibration(), ORIGIN)
    for sp in got:
        strict.feed(sp.packet)
    strict.finish()
    assert strict.skipped.get("depth_no_colour", 0) == len(orphans) == strict.dropped_depth and strict.late_pairs == 0


def test_tracking_loss_without_pose_withholds_both_streams(office, clean):
    got, events = _faulty(office, FaultConfig(tracking_loss=(TrackingLoss(0.6, 0.5, "none"),)))
    withheld = _with(events, "no_pose")
    assert {(e["kind"], e["timestamp_ns"]) for e in withheld} == {
        _key(s) for s in clean if 0.6 <= s.t_s < 1.1}
    assert [s.packet for s in got] == [s.packet for s in clean if not 0.6 <= s.t_s < 1.1]
    pipe, _ = _pipeline(got)
    assert pipe.skipped == {"depth_missing": 3, "colour_missing": 15}  # 0.6, 0.8, 1.0 s; 0.6 … 1.067 s


def test_frozen_tracking_reports_the_first_pose_and_the_pipeline_skips_repeats(office, clean):
    got, events = _faulty(office, FaultConfig(tracking_loss=(TrackingLoss(0.6, 0.7, "frozen"),)))
    sim = _sim(office)
    for a, b in zip(got, clean):
        assert _key(a) == _key(b)
        if 0.6 <= a.t_s < 1.3:
            want = sim.true_pose_depth(0.6) if a.packet.kind == "depth" else sim.true_pose_colour(0.6)
            T = a.packet.T_world_from_depth if a.packet.kind == "depth" else a.packet.T_world_from_colour
            np.testing.assert_array_equal(T.matrix, want.matrix)
            assert a.faults == ("frozen_pose",)
        else:
            assert a.packet == b.packet
    pipe, _ = _pipeline(got)
    # Depth at 0.6, 0.8, 1.0, 1.2 s: the first still differs from 0.4 s's pose, three repeat it.
    assert pipe.skipped.get("depth_pose_frozen") == 3
    # The pose then snaps from 0.6 s's to 1.3 s's (about 9 cm and 40° in 33 ms): a frozen tracker
    # catching up, so the new pose is taken as it is (no hold: 1.4, 1.6, 1.8 s are processed).
    assert set(pipe.skipped) == {"depth_pose_frozen"} and pipe.frozen_resumes == 1
    # without the frozen-pose rule the snap is an unknown jump: the packets within the 1 s hold go
    held, _ = _pipeline(got, pose_check=PoseCheckConfig(skip_frozen=False))
    assert held.skipped.get("depth_pose_jump") == 3 and held.frozen_resumes == 0


def test_pose_jump_offsets_the_reported_pose_and_is_caught(office, clean):
    jump = PoseJump(1.0, 0.5, (0.15, -0.05, 0.0), 8.0)
    got, events = _faulty(office, FaultConfig(pose_jumps=(jump,)))
    for a, b in zip(got, clean):
        T = a.packet.T_world_from_depth if a.packet.kind == "depth" else a.packet.T_world_from_colour
        T0 = b.packet.T_world_from_depth if b.packet.kind == "depth" else b.packet.T_world_from_colour
        if 1.0 <= a.t_s < 1.5:
            np.testing.assert_allclose(T.translation, T0.translation + [0.15, -0.05, 0.0], atol=1e-12)
            c, s = np.cos(np.radians(8.0)), np.sin(np.radians(8.0))
            np.testing.assert_allclose(T.rotation, np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ T0.rotation, atol=1e-12)
        else:
            assert T == T0
    assert len(_with(events, "pose_jump")) == sum(1.0 <= s.t_s < 1.5 for s in clean)
    pipe, _ = _pipeline(got)
    # Snap at 1.0 s (seen by the depth packet itself), back at 1.5 s: every depth packet from 1.0 s is
    # within 1 s of one of them (1.0, 1.2, 1.4; 1.6, 1.8), so no offset pose reaches the map.
    assert pipe.skipped == {"depth_pose_jump": 5}
    from dataclasses import replace

    short = Pipeline(replace(CFG, pose_check=replace(CFG.pose_check, jump_hold_s=0.0, map_check=False)), DEVICE.calibration(), ORIGIN)
    for sp in got:
        short.feed(sp.packet)
    assert short.skipped == {"depth_pose_jump": 2}  # without a hold: only the packet after each jump
    # The map check catches offset packets past the hold: both inside the span (1.2, 1.4 s) are
    # skipped (with the jump undone their points fit the map better), and the snap back may cost one more.
    checked = Pipeline(replace(CFG, pose_check=replace(CFG.pose_check, jump_hold_s=0.0)), DEVICE.calibration(), ORIGIN)
    steps = [r.timestamp_ns for sp in got for r in checked.feed(sp.packet) if isinstance(r, DepthStep)]
    n = checked.skipped.get("depth_inconsistent_with_map", 0)
    assert checked.skipped.get("depth_pose_jump") == 2 and 2 <= n <= 3 and set(checked.skipped) <= {"depth_pose_jump", "depth_inconsistent_with_map"}
    start = min(sp.packet.timestamp_ns for sp in got)
    inside = [t for t in steps if 1.0e9 <= t - start < 1.5e9]
    assert inside == []  # both offset packets (1.2, 1.4 s) are skipped; a third may be after the snap back, before the map vouches


def test_pose_check_can_be_switched_off(office):
    got, _ = _faulty(office, FaultConfig(pose_jumps=(PoseJump(1.0, 0.5, (0.15, 0.0, 0.0)),)))
    from dataclasses import replace

    pipe = Pipeline(replace(CFG, pose_check=replace(CFG.pose_check, enabled=False)), DEVICE.calibration(), ORIGIN)
    for sp in got:
        pipe.feed(sp.packet)
    assert pipe.skipped == {}


def test_timestamp_jitter_moves_stamps_keeps_order_and_looks_poses_up_at_the_stamp(office, clean):
    got, events = _faulty(office, FaultConfig(seed=4, timestamp_jitter_ms=8.0))
    assert len(got) == len(clean)
    by_key = {(s.packet.kind, round(s.t_s, 6)): s for s in clean}
    sim = _sim(office)
    offsets = []
    for sp in got:
        true_ns = sim.start_ns + round(sp.t_s * 1e9)
        off = sp.packet.timestamp_ns - true_ns
        offsets.append(off)
        assert abs(off) <= 8e6 + 1
        ref = by_key[(sp.packet.kind, round(sp.t_s, 6))]
        if sp.packet.kind == "depth":  # the image is the capture's, the pose the stamp's
            np.testing.assert_array_equal(sp.packet.points_m, ref.packet.points_m)
            want = sim.true_pose_depth((sp.packet.timestamp_ns - sim.start_ns) * 1e-9)
            np.testing.assert_allclose(sp.packet.T_world_from_depth.matrix, want.matrix, atol=1e-12)
    assert np.std(offsets) > 3e6  # uniform on ±8 ms: σ = 4.6 ms
    stamps = [(s.packet.timestamp_ns, s.packet.kind != "depth") for s in got]
    assert stamps == sorted(stamps)  # delivered in timestamp order
    assert len(_with(events, "timestamp_jitter")) == sum(1 for o in offsets if o)
    pipe, _ = _pipeline(got)
    # Depth and its frame are at most 16 ms apart (within the 20 ms lag): nothing is skipped.
    assert pipe.skipped == {} and pipe.depth_steps == 10


def test_jitter_beyond_the_pairing_lag_costs_pairs_and_the_pipeline_says_so(office):
    from dataclasses import replace

    got, _ = _faulty(office, FaultConfig(seed=4, timestamp_jitter_ms=8.0))
    pipe = Pipeline(replace(CFG, max_colour_lag_ms=5.0, colour_fallback_lag_ms=None), DEVICE.calibration(), ORIGIN)
    for sp in got:
        pipe.feed(sp.packet)
    pipe.finish()
    stamps: dict = {}
    for sp in got:
        stamps.setdefault(round(sp.t_s, 6), {})[sp.packet.kind] = sp.packet.timestamp_ns
    # Reference: only the same-time frame can be within 5 ms (the others are ≥ 33.3 - 16 ms away).
    far = sum(1 for p in stamps.values() if "depth" in p and abs(p["depth"] - p["colour"]) > 5e6)
    assert 0 < far < 10
    assert pipe.skipped == {"depth_no_colour": far} and pipe.depth_steps == 10 - far
    # With the fallback (50 ms, the default) they pair with their own frame after all: it is the
    # nearest (at most 16 ms away), it only came later than 5 ms allows.
    loose = Pipeline(replace(CFG, max_colour_lag_ms=5.0), DEVICE.calibration(), ORIGIN)
    steps = [r for sp in got for r in loose.feed(sp.packet) if isinstance(r, DepthStep)]
    loose.finish()
    assert loose.skipped == {} and loose.late_pairs == far and loose.depth_steps == 10
    own = {p["depth"]: p["colour"] for p in stamps.values() if "depth" in p}
    assert all(r.colour_timestamp_ns == own[r.timestamp_ns] for r in steps)


def test_reordering_delivers_every_packet_within_the_window(office, clean):
    window = 4
    got, events = _faulty(office, FaultConfig(seed=3, reorder_window=window))
    assert sorted(_key(s) for s in got) == sorted(_key(s) for s in clean)
    position = {_key(s): i for i, s in enumerate(clean)}
    seq = [position[_key(s)] for s in got]
    assert max(abs(i - p) for i, p in enumerate(seq)) < window
    assert seq != sorted(seq)
    marked = [s for s in got if "reordered" in s.faults]
    assert len(marked) == sum(1 for i, p in enumerate(seq) if p < max(seq[:i], default=-1))
    assert len(_with(events, "reordered")) == len(marked)
    # Reference count of what the pipeline must drop: a packet not after the latest of its stream.
    late = {"depth": 0, "colour": 0}
    newest: dict[str, int] = {}
    for s in got:
        k, t = _key(s)
        if t <= newest.get(k, -1):
            late[k] += 1
        newest[k] = max(newest.get(k, -1), t)
    pipe, _ = _pipeline(got)
    for k in ("depth", "colour"):
        assert pipe.skipped.get(f"{k}_out_of_order", 0) == late[k]
    assert sum(late.values()) > 0
    assert not pipe.skipped.get("colour_missing") and not pipe.skipped.get("depth_missing")


def test_frozen_colour_repeats_the_previous_image_and_is_not_used(office, clean):
    got, events = _faulty(office, FaultConfig(seed=5, frozen_colour_p=0.2, frozen_colour_bursts=(Span(1.0, 0.2),)))
    frozen = [i for i, s in enumerate(got) if "frozen_colour" in s.faults]
    assert len(frozen) >= 6
    prev = None
    for s, ref in zip(got, clean):
        if s.packet.kind != "colour":
            continue
        if "frozen_colour" in s.faults:
            np.testing.assert_array_equal(s.packet.nv21, prev)
            assert s.packet.T_world_from_colour == ref.packet.T_world_from_colour
        else:
            assert s.packet == ref.packet
        prev = s.packet.nv21
    pipe, steps = _pipeline(got)
    assert pipe.skipped.get("colour_frozen_frame") == len(frozen)
    # A frozen frame is shown as it is (no object) and never paired with depth.
    frozen_ns = {got[i].packet.timestamp_ns for i in frozen}
    assert all(getattr(r, "colour_timestamp_ns", None) not in frozen_ns for r in steps)


def test_everything_at_once_survives(office):
    faults = FaultConfig(seed=6, depth_dropout_p=0.2, colour_dropout_p=0.1, tracking_loss=(
        TrackingLoss(0.4, 0.3), TrackingLoss(1.2, 0.3, "frozen")), pose_jumps=(PoseJump(0.9, math.inf, (0.05, 0.0, 0.02), 3.0),),
        timestamp_jitter_ms=8.0, reorder_window=3, frozen_colour_p=0.1)
    got, events = _faulty(office, faults)
    assert events and got
    pipe, steps = _pipeline(got)
    assert pipe.skipped and all(v > 0 for v in pipe.skipped.values())
    from rgbd_envmap.pipeline.facade import SKIP_REASONS

    assert set(pipe.skipped) <= set(SKIP_REASONS)


# --- the app: recorded, counted, replayed -----------------------------------------------------------------

SMALL = ["--colour-size", "320x180", "--em-size", "250x125", "--no-render", "--no-video", "--quiet",
         "--preview-envmap-height", "16"]


def test_simulate_records_the_faults_and_the_replay_reproduces_the_live_run(tmp_path):
    import json

    from apps.cli import main

    out = tmp_path / "faulty"
    faults = ["--depth-dropout-burst", "0.4:0.3", "--colour-dropout", "0.1", "--tracking-loss", "1.0:0.3",
              "--tracking-loss", "1.4:0.3:frozen", "--pose-jump", "1.8:inf:0.1:0:0:5", "--timestamp-jitter-ms", "5",
              "--frozen-colour", "0.1", "--fault-seed", "3"]
    assert main(["simulate", "--duration", "2.2", "--out", str(out), *SMALL, *faults]) == 0
    lines = (out / "session" / "groundtruth" / "faults.jsonl").read_text().splitlines()
    config = json.loads(lines[0])["faults"]
    assert config["pose_jumps"][0]["duration_s"] is None and config["timestamp_jitter_ms"] == 5.0
    events = [json.loads(x) for x in lines[1:]]
    run = json.loads((out / "run.json").read_text())
    sim = json.loads((out / "simulation.json").read_text())
    counted: dict[str, int] = {}
    for e in events:
        for f in e["faults"]:
            counted[f] = counted.get(f, 0) + 1
    assert run["faults"] == sim["faults"] == dict(sorted(counted.items()))
    assert {"depth_dropout", "colour_dropout", "no_pose", "frozen_pose", "pose_jump", "frozen_colour"} <= set(counted)
    skipped = run["packets_skipped"]
    assert skipped["depth_no_points"] == counted["depth_dropout"] == 2
    assert skipped["colour_frozen_frame"] == counted["frozen_colour"]
    assert skipped["depth_pose_jump"] >= 1 and skipped["depth_missing"] >= 1
    withheld = {(e["kind"], e["timestamp_ns"]) for e in events if {"no_pose", "colour_dropout"} & set(e["faults"])}
    assert sim["depth_packets"] + sim["colour_packets"] == 11 + 66 - len(withheld)
    with np.load(out / "envmap.npz") as z:
        assert np.isfinite(z["radiance"]).all() and z["valid"].any()
    # The log holds what was delivered; replaying it gives the live run's map bit for bit.
    rep = tmp_path / "replay"
    assert main(["replay", str(out / "session"), "--out", str(rep), *SMALL[2:7]]) == 0
    with np.load(out / "envmap.npz") as a, np.load(rep / "envmap.npz") as b:
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert json.loads((rep / "run.json").read_text())["packets_skipped"] == skipped


def test_simulate_refuses_faults_for_other_devices(tmp_path, capsys):
    from apps.cli import main

    assert main(["simulate", "--duration", "1", "--out", str(tmp_path / "k"), "--device", "kinect",
                 "--depth-dropout", "0.5", *SMALL]) == 2
    assert "only the tango device" in capsys.readouterr().err


def test_fault_options_are_checked_by_the_parser(tmp_path, capsys):
    from apps.cli import main

    for bad in (["--depth-dropout", "2"], ["--tracking-loss", "1:2:lost"], ["--pose-jump", "1:2:0.1"],
                ["--colour-dropout-burst", "1"], ["--frozen-colour-burst", "-1:2"]):
        with pytest.raises(SystemExit) as exc:
            main(["simulate", "--duration", "1", "--out", str(tmp_path / "x"), *bad])
        assert exc.value.code == 2
        assert bad[0] in capsys.readouterr().err


def test_the_map_check_runs_only_after_a_jump_and_gives_a_lasting_offset_up(office, clean):
    # Fault-free: no jump, so nothing is ever checked (the session is the same bit for bit).
    pipe = Pipeline(CFG, DEVICE.calibration(), ORIGIN)
    for sp in clean:
        pipe.feed(sp.packet)
        assert pipe.map_consistency is None
    assert pipe.skipped == {} and pipe.map_check_accepted == 0
    # An offset that stays from 0.8 s: with a short hold, the packets after it are tested.
    got, _ = _faulty(office, FaultConfig(pose_jumps=(PoseJump(0.8, math.inf, (0.15, -0.05, 0.0), 8.0),)))
    hold = replace(CFG.pose_check, jump_hold_s=0.2)
    never = Pipeline(replace(CFG, pose_check=replace(hold, map_accept_after_s=None)), DEVICE.calibration(), ORIGIN)
    for sp in got:
        never.feed(sp.packet)
    tested = never.skipped.get("depth_inconsistent_with_map", 0)
    assert tested >= 2 and never.map_check_accepted == 0  # of the five packets 1.0 … 1.8 s
    # Given up 0.5 s after the jump: nothing is skipped for the map after that, once accepted.
    soon = Pipeline(replace(CFG, pose_check=replace(hold, map_accept_after_s=0.5)), DEVICE.calibration(), ORIGIN)
    skipped_at = []
    for sp in got:
        before = soon.skipped.get("depth_inconsistent_with_map", 0)
        soon.feed(sp.packet)
        if soon.skipped.get("depth_inconsistent_with_map", 0) > before:
            skipped_at.append(sp.t_s)
    assert soon.map_check_accepted == 1 and all(t < 1.3 for t in skipped_at)
    assert soon.depth_steps > never.depth_steps
