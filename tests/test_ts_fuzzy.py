"""TS fuzzy model (paper 003): RLS form, model output, GA identification, trainer, compensation."""

import numpy as np
import pytest

from fedtrack.config import ConfigError
from fedtrack.experiments.input_estimation import EVAL_TAG, scenario_rng
from fedtrack.experiments.ts_fuzzy import main
from fedtrack.local_filters.radar.ekf import motion_model_3d
from fedtrack.local_filters.radar.filters import EkfTsFuzzyConfig, filter_kind, run_batch
from fedtrack.local_filters.radar.ts_fuzzy import GAParams, TSModel, identify, load_model, predict, rls, save_model
from fedtrack.sensors.radar import RadarConfig, simulate


def test_block_rls_equals_sample_by_sample_and_least_squares():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(300, 8))
    Y = X @ rng.normal(size=(8, 2)) + 0.1 * rng.normal(size=(300, 2))
    theta0, S0 = np.zeros((8, 2)), 1e3 * np.eye(8)
    seq = rls(theta0, S0, X, Y, block=1)
    blk = rls(theta0, S0, X, Y, block=64)
    np.testing.assert_allclose(blk[0], seq[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(blk[1], seq[1], rtol=1e-7, atol=1e-12)
    # with S0 = alpha I the recursion is ridge LS with penalty 1/alpha (exact)
    ridge = np.linalg.solve(X.T @ X + 1e-3 * np.eye(8), X.T @ Y)
    np.testing.assert_allclose(blk[0], ridge, rtol=1e-9, atol=1e-9)


def test_single_rule_model_is_affine_and_rules_blend():
    one = TSModel(np.zeros((1, 2)), np.ones((1, 2)), np.array([[[1.0], [2.0], [-3.0]]]),
                  np.zeros(2), np.ones(2), np.zeros(1), np.ones(1))
    x = np.random.default_rng(1).normal(size=(5, 2)) * 100.0
    np.testing.assert_allclose(predict(one, x)[:, 0], 1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1], rtol=1e-12)
    two = TSModel(np.array([[-1.0], [1.0]]), np.ones((2, 1)), np.array([[[0.0], [0.0]], [[1.0], [0.0]]]),
                  np.zeros(1), np.ones(1), np.zeros(1), np.ones(1))
    # at the midpoint both rules fire equally; far away one rule dominates (log-space weights)
    np.testing.assert_allclose(predict(two, np.array([[0.0], [50.0], [-50.0]]))[:, 0], [0.5, 1.0, 0.0], atol=1e-12)


def test_ga_identifies_a_nonlinear_map_with_few_rules():
    rng = np.random.default_rng(3)
    x = rng.uniform(-3, 3, size=(3000, 1))
    y = np.abs(x)  # two affine pieces
    params = GAParams(population=30, generations=15, max_rules=6, fit_samples=300, val_samples=300,
                      rls_samples=2000)
    model, summary = identify(x, y, params, rng)
    assert 2 <= summary["rules"] <= 6
    assert summary["rls_val_mse"] < 0.05  # standardized; a linear fit leaves ~1.0
    xt = np.linspace(-2.5, 2.5, 11)[:, None]
    assert np.max(np.abs(predict(model, xt) - np.abs(xt))) < 0.3


def test_model_file_round_trip_and_bad_file(tmp_path):
    m = TSModel(np.zeros((2, 3)), np.ones((2, 3)), np.ones((2, 4, 6)), np.zeros(3), np.ones(3),
                np.zeros(6), np.ones(6))
    save_model(tmp_path / "m", m, train_seed=3)  # written whole, under the name given (numpy's savez adds .npz)
    assert [p.name for p in tmp_path.iterdir()] == ["m"]
    back, meta = load_model(tmp_path / "m")
    for a, b in zip(back, m):
        np.testing.assert_array_equal(a, b)
    assert int(meta["train_seed"]) == 3
    (tmp_path / "bad.npz").write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="model"):
        load_model(tmp_path / "bad.npz")


def test_trainer_cli_and_compensation_on_held_out_runs(tmp_path, capsys):
    out = tmp_path / "ts.npz"
    assert main(["--runs", "2", "--seed", "5", "--out", str(out), "--population", "16",
                 "--generations", "3", "--max-rules", "4"]) == 0
    assert "rules" in capsys.readouterr().out
    ts, meta = load_model(out)
    assert 1 <= ts.n_rules <= 4 and int(meta["train_seed"]) == 5
    cfg = RadarConfig()
    traj, zs = simulate(cfg, 3, scenario_rng(EVAL_TAG, 5))
    m = motion_model_3d("cv", cfg.T, 1.0)
    sensor = np.zeros(3)
    tcfg = EkfTsFuzzyConfig(model=str(out))
    plain = run_batch(filter_kind("ekf", tcfg), zs, cfg.R, sensor, m)
    comp = run_batch(filter_kind("ekf-tsfuzzy", tcfg), zs, cfg.R, sensor, m)
    mse = [np.mean((r.x[:, 1:][..., [0, 2, 4]] - traj.pos[1:]) ** 2, axis=(0, 1)) for r in (plain, comp)]
    assert np.all(mse[1] < mse[0]), mse
