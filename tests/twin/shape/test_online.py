"""`twin run compress --predict MODEL`: the contour predicted from every hand reading is recorded and
drawn beside the camera's, and a model is checked before any run starts."""

import re

import numpy as np
import pytest

from twin.cli import main
from twin.recording.reader import Run
from twin.session import RRD_NAME
from twin.shape.model import ShapeMLP, ShapeModel
from twin.viz.rerun_log import RECTIFIED_ENTITY, read_rrd_entities


@pytest.fixture
def model_dir(tmp_path):
    rng = np.random.default_rng(0)
    model = ShapeModel(
        net=ShapeMLP(16),
        x_mean=np.array([12000, 12000, 12000, 0.2, 0.2, 0.2]),
        x_std=np.array([500, 500, 500, 0.1, 0.1, 0.1]),
        y_mean=rng.uniform(100, 200, 32),
        y_std=np.full(32, 5.0),
        metadata={"object": "sphere"},
    )
    return model.save(tmp_path / "model")


@pytest.mark.slow
def test_a_run_predicts_every_hand_sample_and_records_the_measured_contour(model_dir, tmp_path):
    out = tmp_path / "run"
    argv = [
        "run",
        "compress",
        "--object",
        "sphere",
        "--duration",
        "3",
        "--cameras",
        "--predict",
        str(model_dir),
    ]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    run = Run(out)
    hand, shape, contour = run.stream("hand"), run.stream("shape"), run.stream("contour")
    assert len(shape) == len(hand) and np.array_equal(shape.t_s, hand.t_s)
    model = ShapeModel.load(model_dir)
    inputs = np.column_stack([hand["position_counts"][:, :3], hand["torque_nm"]])
    assert np.allclose(shape["contour_px"], model.predict(inputs), atol=1e-3)
    assert len(contour) > 60 and contour["contour_px"].shape[1:] == (16, 2)
    assert ((contour["contour_px"] >= 0) & (contour["contour_px"] <= 320)).all()
    entities = read_rrd_entities(out / RRD_NAME)
    assert f"/{RECTIFIED_ENTITY}/contour/predicted".replace("//", "/") in entities
    assert f"/{RECTIFIED_ENTITY}/contour/measured".replace("//", "/") in entities


def test_a_model_that_is_not_one_or_for_another_object_is_refused_before_the_run(model_dir, tmp_path, capsys):
    surface = ShapeModel(
        net=ShapeMLP(16, dims=1),
        x_mean=np.zeros(6),
        x_std=np.ones(6),
        y_mean=np.zeros(16),
        y_std=np.ones(16),
        metadata={"object": "block", "target": "surface"},
    ).save(tmp_path / "surface")
    for model, message in (
        (tmp_path, "not a trained shape model"),
        (model_dir, "trained on 'sphere'"),
        (surface, "a surface model"),
    ):
        out = tmp_path / "never"
        argv = ["run", "compress", "--object", "block", "--predict", str(model), "--out", str(out)]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and not out.exists()


def test_a_model_from_another_camera_view_is_refused_before_the_run(tmp_path, capsys):
    """A model learned from top-view contours, on a run whose cameras stand at the paper's lateral view
    (the default), would predict another view's pixels: one line, exit 2, nothing written. The same
    model with the view its sweep records for these cameras passes the check."""
    from twin.shape.surface import TOP_VIEW
    from twin.sim.backend import SimBackend
    from twin.sim.foam import get_object
    from twin.vision.contour import view_from_hand
    from twin.vision.reconstruct import Rectifier

    def saved(view, name):
        return ShapeModel(
            net=ShapeMLP(16),
            x_mean=np.zeros(6),
            x_std=np.ones(6),
            y_mean=np.zeros(32),
            y_std=np.ones(32),
            metadata={"object": "sphere", "view_from_hand": view},
        ).save(tmp_path / name)

    out = tmp_path / "never"
    argv = ["run", "compress", "--object", "sphere", "--cameras", "--out", str(out), "--no-progress"]
    assert main([*argv, "--predict", str(saved([list(row) for row in TOP_VIEW], "top"))]) == 2
    err = capsys.readouterr().err
    angle = re.search(r"seen from (\d+) deg away from where these cameras stand", err)
    assert err.count("\n") == 1 and angle and 55 <= int(angle.group(1)) <= 65 and "Traceback" not in err
    assert not out.exists()
    backend = SimBackend(get_object("sphere"), stereo=True)
    lateral = view_from_hand(Rectifier(backend.stereo.calibration()))
    ShapeModel.load(saved(lateral.tolist(), "lateral")).check_view(lateral)  # passes
