"""The shape network's pieces on data whose answer is known: normalization folded into the fast path,
save/load, trajectory-wise splits, and a network that beats both baselines on a nonlinear contour."""

import numpy as np
import pytest

from twin.interface.errors import ConfigError
from twin.shape.dataset import ShapeData, split_by_trajectory
from twin.shape.model import ShapeMLP, ShapeModel
from twin.shape.train import NETWORK, cross_validate, train


def _synthetic(trajectories=12, per=120, points=8, seed=0) -> ShapeData:
    """A 'contour' that bulges nonlinearly with the finger inputs (a circle pushed by three fingers)."""
    rng = np.random.default_rng(seed)
    xs, px, traj = [], [], []
    angles = np.linspace(0, 2 * np.pi, points, endpoint=False)
    for k in range(trajectories):
        t = np.linspace(0, 6, per)
        phase, freq = rng.uniform(0, 2 * np.pi, 3), rng.uniform(0.2, 0.8, 3)
        p = 12000 + 200 * (1 + np.sin(2 * np.pi * freq * t[:, None] + phase))  # counts
        torque = 0.2 + 0.001 * (p - 12000) ** 1.2 / 10  # N*m, a stiffening foam
        dent = np.tanh((p - 12200) / 150)  # (n, 3)
        radius = 40 - 3 * dent @ np.cos(angles[None, :] - np.array([0, 2.1, 4.2])[:, None])
        xs.append(np.column_stack([p, torque]))
        px.append(np.stack([160 + radius * np.cos(angles), 120 - radius * np.sin(angles)], axis=2))
        traj.append(np.full(per, k))
    contour_px = np.concatenate(px)
    return ShapeData(np.concatenate(xs), contour_px, 0.5 * contour_px, np.concatenate(traj))


def test_held_out_trajectories_are_whole():
    data = _synthetic()
    tr, val = split_by_trajectory(data, 0.25, seed=3)
    assert set(np.unique(tr.trajectory)).isdisjoint(np.unique(val.trajectory))
    assert len(np.unique(val.trajectory)) == 3 and len(tr) + len(val) == len(data)


@pytest.mark.parametrize("fraction", [0.96, 0.999, 1.0])
def test_a_held_out_fraction_that_leaves_nothing_to_train_on_is_one_line(fraction):
    """`train --validation 0.999` once reshaped an empty training set (issue 37): now one line."""
    with pytest.raises(ConfigError, match="leaving none to train on"):
        split_by_trajectory(_synthetic(trajectories=12, per=4), fraction, seed=0)


def test_fast_numpy_prediction_equals_torch_and_survives_save_load(tmp_path):
    rng = np.random.default_rng(1)
    model = ShapeModel(
        net=ShapeMLP(8),
        x_mean=rng.normal(size=6),
        x_std=rng.uniform(0.5, 2, 6),
        y_mean=rng.normal(size=16),
        y_std=rng.uniform(0.5, 2, 16),
        metadata={"object": "sphere"},
    )
    x = rng.normal(size=(5, 6))
    assert np.allclose(model.predict(x), model.predict_torch(x), atol=1e-4)
    again = ShapeModel.load(model.save(tmp_path / "m"))
    assert np.allclose(again.predict(x), model.predict(x)) and again.metadata["object"] == "sphere"
    assert model.predict(x[0]).shape == (8, 2)
    (tmp_path / "bad").mkdir()
    with pytest.raises(ValueError, match="not a trained shape model"):
        ShapeModel.load(tmp_path / "bad")


@pytest.mark.slow
def test_the_network_learns_a_nonlinear_contour_and_beats_the_baselines():
    result = train(_synthetic(), epochs=1500, seed=0)
    errors = {e.name.split()[0]: e.error_px for e in result.evaluations}
    assert errors["network"] < 0.5 * errors["linear"] and errors["network"] < errors["nearest"]
    assert errors["network"] < 0.5  # px, on trajectories it never saw
    mm = {e.name.split()[0]: e.error_mm for e in result.evaluations}
    assert mm["network"] == pytest.approx(0.5 * errors["network"], rel=1e-6)  # the data's 0.5 mm/px


@pytest.mark.slow
def test_cross_validation_scores_every_trajectory_on_networks_that_never_saw_it():
    data = _synthetic()
    # trajectory 5 is unlike the others (its torques 0.3 N*m higher, its contour 4 px to the right):
    # a network that never saw it cannot know the shift; one trained on it can
    on = data.trajectory == 5
    inputs, contour = data.inputs.copy(), data.contour_px.copy()
    inputs[on, 3:] += 0.3
    contour[on, :, 0] += 4.0
    data = ShapeData(inputs, contour, 0.5 * contour, data.trajectory)
    cv = cross_validate(data, folds=4, epochs=1500, seed=0)
    ids = sorted(int(t) for t in np.unique(data.trajectory))
    assert sorted(t for fold in cv.folds for t in fold) == ids and len(cv.folds) == 4
    assert sorted(cv.trajectory_errors_px) == ids
    assert [e.name.split()[0] for e in cv.evaluations] == ["network", "linear", "nearest"]
    # pooled over every held-out sample: the folds' errors weighted by their samples
    sizes = [np.isin(data.trajectory, fold).sum() for fold in cv.folds]
    network = cv.fold_errors_px[NETWORK]
    assert cv.evaluations[0].error_px == pytest.approx(np.average(network, weights=sizes), rel=1e-9)
    assert cv.trajectory_errors_px[5] > 3.0  # px: scored by a network that never saw it
    assert max(v for k, v in cv.trajectory_errors_px.items() if k != 5) < 0.2
    kept = np.linalg.norm(cv.model.predict(inputs[on]) - contour[on], axis=2).mean()
    assert kept < 0.2  # the kept model was trained on every trajectory, 5 included
    assert cv.model.metadata["cross_validation"]["folds"] == cv.folds
    with pytest.raises(ConfigError, match="folds must be 2 to 12"):
        cross_validate(data, folds=13, epochs=5)
