"""Sweeps: seeded trajectories, files that appear whole, resumption, and the Ray executor producing
the local executor's dataset (against a local Ray instance)."""

import json

import numpy as np
import pytest
from twin.experiments.sweep import TrajectoryController, draw_trajectories, read_index, sweep

from twin.cli import main
from twin.interface.errors import ConfigError
from twin.recording.reader import Run

DURATION_S = 6.5  # the grasp settles at ~3.5 s; then 3 s of varied compression


def test_trajectories_are_seeded_per_index_and_vary_per_finger():
    a = draw_trajectories(["sphere"], 4, seed=7, duration_s=10, points=16)
    b = draw_trajectories(["sphere"], 6, seed=7, duration_s=10, points=16)
    assert a == b[:4]  # drawing more does not change the first ones
    assert a != draw_trajectories(["sphere"], 4, seed=8, duration_s=10, points=16)
    assert all(len(set(t.frequency_hz)) == 3 and len(set(t.phase_rad)) == 3 for t in a)


def test_every_finger_starts_its_wave_at_the_grasp_and_presses_at_most_400_counts():
    (t,) = draw_trajectories(["sphere"], 1, seed=0, duration_s=10, points=16)
    c = TrajectoryController(t)
    c.grasp_counts, c._t_phase, c.phase = np.array([12000.0, 12000.0, 11800.0]), 5.0, "compress"
    assert np.allclose(c._compress(5.0), c.grasp_counts)
    waves = np.array([c._compress(5.0 + s) - c.grasp_counts for s in np.linspace(0, 20, 400)])
    assert waves.min() >= 0 and waves.max() <= 400 + 1e-9


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "local"
    trajectories = draw_trajectories(["sphere"], 2, seed=3, duration_s=DURATION_S, points=16)
    return out, trajectories, sweep(trajectories, out, workers=2)


@pytest.mark.slow
def test_a_local_sweep_writes_whole_files_and_an_index(local_dataset):
    out, trajectories, entries = local_dataset
    assert [e["file"] for e in entries] == [f"{t.name}.npz" for t in trajectories]
    assert read_index(out) == entries
    for e in entries:
        with np.load(out / e["file"]) as d:
            n = len(d["t_s"])
            assert n == e["samples"] > 60 and d["contour_px"].shape == d["hull_px"].shape == (n, 16, 2)
            assert d["position_counts"].shape == d["torque_nm"].shape == (n, 3)
            assert np.isfinite(d["contour_mm"]).all() and np.isfinite(d["hull_mm"]).all()
            assert "surface_mm" not in d.files  # only with surface=True
            assert json.loads(str(d["trajectory"]))["index"] == e["index"]
    assert not list(out.glob("*.tmp*"))


def test_a_rerun_skips_finished_trajectories(local_dataset):
    out, trajectories, entries = local_dataset
    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}
    progress = []
    again = sweep(trajectories, out, workers=2, progress=lambda done, total: progress.append((done, total)))
    assert again == entries and progress == [(2, 2)]
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == stamps


@pytest.mark.slow
def test_ray_produces_the_local_dataset(local_dataset, tmp_path):
    out, trajectories, _ = local_dataset
    entries = sweep(trajectories, tmp_path / "ray", workers=2, executor="ray")
    for e in entries:
        with np.load(out / e["file"]) as a, np.load(tmp_path / "ray" / e["file"]) as b:
            for key in (
                "t_s",
                "position_counts",
                "torque_nm",
                "contour_px",
                "contour_mm",
                "hull_px",
                "hull_mm",
            ):
                assert np.array_equal(a[key], b[key]), key


def test_a_damaged_trajectory_file_is_named_in_one_line(local_dataset, tmp_path, capsys):
    import shutil

    out, _, entries = local_dataset
    damaged = tmp_path / "damaged"
    shutil.copytree(out, damaged)
    (damaged / entries[0]["file"]).write_bytes(b"PK\x03\x04 not a zip")
    assert main(["train", str(damaged), "--object", "sphere"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{entries[0]['file']}: not a readable trajectory" in err


def test_bad_sweep_input_is_one_line(tmp_path, capsys):
    for argv, message in (
        (["sweep", "--objects", "teapot", "--out", str(tmp_path / "x")], "unknown object 'teapot'"),
        (["sweep", "--duration", "3", "--out", str(tmp_path / "x")], "--duration: must be a finite number"),
        (
            ["sweep", "--executor", "local", "--address", "ray://h:1", "--out", str(tmp_path / "x")],
            "--address",
        ),
        (["train", str(tmp_path / "none"), "--object", "sphere"], "not a sweep dataset"),
        # nothing listens on port 1 of this machine: refused at once, not after ray.init's minutes of retries
        (
            ["sweep", "--executor", "ray", "--address", "127.0.0.1:1", "--out", str(tmp_path / "x")],
            "no Ray cluster answers there",
        ),
        (["sweep", "--executor", "ray", "--address", "headnode", "--out", str(tmp_path / "x")], "host:port"),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "x").exists()
    with pytest.raises(ConfigError, match="unknown executor"):
        sweep([], tmp_path / "y", executor="dask")


@pytest.mark.slow
def test_a_recorded_camera_run_becomes_a_dataset_trajectory(tmp_path, capsys):
    """The hardware path: recorded frames (as JPEG) through the same contour code, paired with the
    hand readings; shown on a sim run recorded with --cameras."""
    run = tmp_path / "run"
    argv = ["run", "compress", "--object", "sphere", "--duration", "6", "--cameras", "--no-progress"]
    assert main([*argv, "--out", str(run)]) == 0
    assert main(["sweep", "--from-runs", str(run), "--out", str(tmp_path / "ds"), "--points", "16"]) == 0
    (entry,) = read_index(tmp_path / "ds")
    with np.load(tmp_path / "ds" / entry["file"]) as d:
        n = len(d["t_s"])
        assert n == entry["samples"] > 40 and d["contour_px"].shape == (n, 16, 2)
        hand = Run(run).stream("hand")
        i = np.searchsorted(hand.t_s, d["t_s"], side="right") - 1
        assert np.array_equal(d["position_counts"], hand["position_counts"][i, :3])
        # contours of the grasped sphere: in the image, and over the palm in the hand frame
        assert ((d["contour_px"] > 0) & (d["contour_px"] < 320)).all()
        assert np.isfinite(d["contour_mm"]).all() and (np.abs(d["contour_mm"]) < 60).all()
        # the recorded fused cloud, as heights on a grid laid on the first frame's cloud
        assert d["surface_mm"].shape == (n, 100) and np.isfinite(d["surface_mm"]).any()
        assert "surface_truth_mm" not in d.files
        # one sample per recorded frame of the compression (the sphere is never lost)
        stereo = Run(run).stream("stereo")
        assert entry["lost_frames"] == 0 and n <= len(stereo) and np.isin(d["t_s"], stereo.t_s).all()
    capsys.readouterr()
    assert main(["sweep", "--from-runs", str(tmp_path / "nothing"), "--out", str(tmp_path / "ds")]) == 2
    assert "not a run directory" in capsys.readouterr().err


@pytest.mark.slow
def test_a_surface_sweep_keeps_heights_near_the_true_surface_and_trains_the_3d_variant(
    local_dataset, tmp_path, capsys
):
    out = tmp_path / "surface"
    trajectories = draw_trajectories(["block"], 2, seed=1, duration_s=DURATION_S, points=16, surface=True)
    entries = sweep(trajectories, out, workers=2)
    for e in entries:
        assert e["surface"] is True
        with np.load(out / e["file"]) as d:
            n = len(d["t_s"])
            heights, truth = d["surface_mm"], d["surface_truth_mm"]
            assert heights.shape == truth.shape == (n, 100)
            both = np.isfinite(heights) & np.isfinite(truth)
            # the foam where the fingers leave it in view: ~42 of 100 cells a frame from the paper's
            # lateral view (8 from the top), their heights 0.37 mm from the true surface (median)
            assert both.sum() > 20 * n
            assert np.median(np.abs(heights - truth)[both]) < 0.6  # mm
            assert json.loads(str(d["surface_grid"]))["cells"] == 10
    capsys.readouterr()
    argv = [
        "train",
        str(out),
        "--object",
        "block",
        "--target",
        "surface",
        "--epochs",
        "50",
        "--validation",
        "0.5",
    ]
    assert main(argv) == 0
    report = json.loads((out / "models" / "block-surface" / "evaluation.json").read_text())
    assert [r["predictor"].split()[0] for r in report["held_out"]] == ["network", "linear", "nearest"]
    assert all(r["error_mm"] > 0 for r in report["held_out"])
    # a dataset swept without --surface: one line naming the missing column
    contours, _, _ = local_dataset
    assert main(["train", str(contours), "--object", "sphere", "--target", "surface"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no 'surface_mm' column" in err


def test_train_cross_validates_by_trajectory_and_keeps_a_hull_model_trained_on_all(local_dataset, capsys):
    out, trajectories, _ = local_dataset
    capsys.readouterr()
    assert main(["train", str(out), "--object", "sphere", "--epochs", "50"]) == 0
    printed = capsys.readouterr().out
    assert "2 trajectories in 2 folds" in printed  # fewer trajectories than 4: one fold each
    model_dir = out / "models" / "sphere"  # the hull is the default target
    report = json.loads((model_dir / "evaluation.json").read_text())
    assert sorted(t for fold in report["folds"] for t in fold) == [t.index for t in trajectories]
    assert set(report["trajectory_errors_px"]) == {str(t.index) for t in trajectories}
    assert [r["predictor"].split()[0] for r in report["held_out"]] == ["network", "linear", "nearest"]
    assert all(np.isfinite(r["error_px"]) and r["error_px"] > 0 for r in report["held_out"])
    meta = json.loads((model_dir / "model.json").read_text())
    assert meta["target"] == "hull" and meta["cross_validation"]["folds"] == report["folds"]
    # the cameras' view the contours were traced in (the default, lateral: 30 deg above the palm plane)
    toward = np.asarray(meta["view_from_hand"])[2]
    assert np.degrees(np.arcsin(toward[2])) == pytest.approx(30.0, abs=5.0)
    for argv, message in (
        (["--folds", "1"], "argument --folds: must be an integer >= 2"),
        (["--folds", "0"], "argument --folds: must be an integer >= 2"),
        (["--folds", "3"], "folds must be 2 to 2"),
        (["--folds", "2", "--validation", "0.5"], "choose one way"),
        (["--validation", "1.5"], "argument --validation: must be a finite number > 0 and < 1"),
        (["--target", "surface", "--folds", "2"], "one held-out split"),
    ):
        assert main(["train", str(out), "--object", "sphere", "--epochs", "5", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
