"""Every ``fedtrack reproduce`` says what it does and prints its results table; ts-fuzzy takes
``--model`` and announces the training it would otherwise do."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest
from support import in_parallel

from fedtrack import cli

TITLES = {"fvdie": "x position RMS error", "vsimm": "acceleration RMS error", "hpda": "Table 2:",
          "input-estimation": "paper 002: position error", "ts-fuzzy": "paper 003: position error"}


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("model") / "m.npz"
    assert cli.main(["train", "ts-fuzzy", "--runs", "2", "--generations", "2", "--population", "8",
                     "--out", str(out)]) == 0
    return out


def reproduce(name: str, json_path: Path, model: Path) -> tuple[int, str, str]:
    """``fedtrack reproduce NAME --runs 2 --seed 3`` (``--model`` for ts-fuzzy) in this process: its
    exit code, standard output and standard error."""
    out, err = io.StringIO(), io.StringIO()
    extra = ["--model", str(model)] if name == "ts-fuzzy" else []
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(["reproduce", name, "--runs", "2", "--seed", "3", "--json", str(json_path), *extra])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory: pytest.TempPathFactory, tiny_model: Path) -> dict[str, tuple[int, str, str]]:
    """``reproduce`` of every reproducer, by name: independent runs, over two processes (hpda, as
    long as the others together, first)."""
    names = sorted(cli.REPRODUCERS, key=lambda name: name != "hpda")
    out = tmp_path_factory.mktemp("reproduce")
    return dict(zip(names, in_parallel([(reproduce, (name, out / f"{name}.json", tiny_model)) for name in names])))


@pytest.mark.parametrize("name", sorted(cli.REPRODUCERS))
def test_reproduce_announces_and_prints_its_table(name: str, reproduced: dict[str, tuple[int, str, str]]) -> None:
    code, out, err = reproduced[name]
    assert code == 0, err
    assert f"reproduce {name}: paper" in err
    assert TITLES[name] in out and "+-" in out, out


def test_ts_fuzzy_says_it_trains(tmp_path: Path, tiny_model: Path, monkeypatch: pytest.MonkeyPatch,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    from fedtrack.experiments import ts_fuzzy
    from fedtrack.local_filters.radar.ts_fuzzy import load_model

    trained = []

    def fake_train(runs: int, seed: int, ga: object, q: float) -> tuple:
        trained.append(ga)
        return load_model(tiny_model)[0], {"rules": 1, "train_wall_s": 0.0}

    monkeypatch.delenv(ts_fuzzy.MODEL_ENV, raising=False)
    monkeypatch.setattr(ts_fuzzy, "train", fake_train)
    assert cli.main(["reproduce", "ts-fuzzy", "--runs", "2", "--json", str(tmp_path / "r.json")]) == 0
    assert f"training a model: {ts_fuzzy.GAParams().generations} generations" in capsys.readouterr().err
    assert len(trained) == 1
    with pytest.raises(SystemExit) as exc:
        cli.main(["reproduce", "vsimm", "--runs", "2", "--json", str(tmp_path / "v.json"), "--model", str(tiny_model)])
    assert exc.value.code == 2


@pytest.mark.parametrize("given", ["--model", "env"])
def test_ts_fuzzy_names_where_a_missing_model_was_given(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str], given: str) -> None:
    """A model file that is not there is named by where it was given: ``--model``, or
    ``$FEDTRACK_TS_FUZZY_MODEL`` (before tour57 the environment's path was reported as ``--model``'s)."""
    from fedtrack.experiments import ts_fuzzy

    missing = tmp_path / "gone.npz"
    argv = ["reproduce", "ts-fuzzy", "--runs", "2", "--json", str(tmp_path / "r.json")]
    if given == "env":
        monkeypatch.setenv(ts_fuzzy.MODEL_ENV, str(missing))
    else:
        monkeypatch.delenv(ts_fuzzy.MODEL_ENV, raising=False)
        argv += ["--model", str(missing)]
    assert cli.main(argv) == 2
    named = "--model" if given == "--model" else f"${ts_fuzzy.MODEL_ENV}"
    assert f"error: {named}: {missing} does not exist" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()
