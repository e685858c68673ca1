"""``evaluate --plot``'s figure: regions and hand-overs, many targets thinned, units, legends, titles."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from fedtrack.cli import main

matplotlib = pytest.importorskip("matplotlib")


def write_lines(path: Path, rows: list[dict[str, Any]]) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def scene(tmp_path: Path, targets: int, spacing: float = 100.0, speed: float = 10.0, steps: int = 20,
          detector: str = "none", tracked: bool = True) -> tuple[Path, Path]:
    """``targets`` moving along x from x = -100 m (side by side ``spacing`` apart in y), each tracked
    exactly when ``tracked``."""
    truth = [{"t": float(k), "targets": [{"id": i, "x": [-100.0 + speed * k, speed, spacing * i, 0.0]}
                                         for i in range(targets)]} for k in range(steps)]
    tracks = [{"t": row["t"], "algorithm": "mtt-federated", "detector": detector,
               "tracks": [{"id": 100 + g["id"], "x": g["x"], "status": "confirmed"} for g in row["targets"]]
               if tracked else []} for row in truth]
    return write_lines(tmp_path / "tracks.jsonl", tracks), write_lines(tmp_path / "truth.jsonl", truth)


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Every figure saved while the test runs."""
    from matplotlib.figure import Figure

    saved: list[Any] = []
    original = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: (saved.append(self), original(self, *a, **k)))
    return saved


def evaluate_plot(tmp_path: Path, tracks: Path, truth: Path, *extra: str) -> Any:
    argv = ["evaluate", "--tracks", str(tracks), "--truth", str(truth), "--plot", str(tmp_path / "p.png"), *extra]
    assert main(argv) == 0
    return argv


def legend_texts(ax: Any) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_regions_borders_and_the_border_crossings_are_drawn(tmp_path: Path, figures: list[Any]) -> None:
    tracks, truth = scene(tmp_path, targets=2)  # both cross x = 0 between t = 10 and 11
    config = tmp_path / "c.toml"
    config.write_text("[regions]\nmargin = 50.0\n"
                      "grid = {origin = [-200.0, -200.0], cell = [200.0, 500.0], nx = 2, ny = 1}\n")
    evaluate_plot(tmp_path, tracks, truth, "--config", str(config))
    (fig,) = figures
    ax = fig.axes[0]
    borders = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert len(borders) == 2 and {t.get_text() for t in ax.texts} == {"x0y0", "x1y0"}
    (crossings,) = [c for c in ax.collections if "hand-over" in c.get_label()]
    assert crossings.get_offsets().tolist() == [[5.0, 0.0], [5.0, 100.0]]  # midway between t = 10 and 11
    assert "region borders (2)" in legend_texts(ax) and "track crosses a border: hand-over (2)" in legend_texts(ax)


def test_many_targets_are_drawn_as_the_last_windows_trails_and_the_title_says_so(
        tmp_path: Path, figures: list[Any], monkeypatch: pytest.MonkeyPatch) -> None:
    from fedtrack.fusion_center.mtt.evaluation import figures as module

    monkeypatch.setattr(module, "MAX_PATHS", 5)  # the rule at 10 targets, not 500 (fast)
    n = 10
    tracks, truth = scene(tmp_path, targets=n, spacing=10.0, steps=21)  # 20 s: a window of 10 s
    evaluate_plot(tmp_path, tracks, truth)
    ax = figures[0].axes[0]
    lines = ax.get_lines()
    assert len(lines) == 2 * n  # every truth and track, each over t = 10..20 only: x from 0 to 100
    assert all(line.get_xdata()[0] == 0.0 and line.get_xdata()[-1] == 100.0 for line in lines)
    assert f"{n} targets: only the last 10 s of 20 s drawn" in ax.get_title()
    assert f"truth ({n} targets)" in legend_texts(ax)


def test_a_few_targets_whole_in_metres_no_borders_and_legends_outside_their_axes(
        tmp_path: Path, figures: list[Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    tracks, truth = scene(tmp_path, targets=3)
    evaluate_plot(tmp_path, tracks, truth)
    fig = figures[0]
    ax = fig.axes[0]
    assert all(line.get_xdata()[0] == -100.0 for line in ax.get_lines()) and "targets:" not in ax.get_title()
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    assert not [line for line in ax.get_lines() if line.get_linestyle() == "--"] and not ax.collections
    renderer = FigureCanvasAgg(fig).get_renderer()
    for panel in fig.axes:
        legend, frame = panel.get_legend().get_window_extent(renderer), panel.get_window_extent(renderer)
        assert legend.y1 <= frame.y0, (panel.get_title(), legend, frame)


def test_a_wide_scene_is_drawn_in_km(tmp_path: Path, figures: list[Any]) -> None:
    tracks, truth = scene(tmp_path, targets=2, speed=2000.0)  # 38 km along x
    evaluate_plot(tmp_path, tracks, truth)
    ax = figures[0].axes[0]
    assert ax.get_xlabel() == "x [km]" and ax.get_ylabel() == "y [km]"
    assert max(line.get_xdata().max() for line in ax.get_lines()) == pytest.approx(37.9)


def test_the_title_names_the_maneuver_detector_and_empty_panels_say_why(tmp_path: Path, figures: list[Any]) -> None:
    tracks, truth = scene(tmp_path, targets=2, detector="vdie", tracked=False)
    evaluate_plot(tmp_path, tracks, truth)
    fig = figures[0]
    assert fig._suptitle.get_text() == "mtt-federated (maneuver detector vdie): tracks.jsonl"
    assert [t.get_text() for t in fig.axes[0].texts] == ["no confirmed track in tracks.jsonl"]
    assert "confirmed tracks (0), a colour each" in legend_texts(fig.axes[0])


def test_vsimm_active_groups_legend_is_beside_the_axes_and_the_axis_named(tmp_path: Path, figures: list[Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from fedtrack.experiments.vsimm import _plot

    series = {"t": [1, 2, 3], "rms_acc_x": [1.0, 2.0, 1.0], "rms_acc_y": [1.0, 1.0, 2.0]}
    groups = {key: {"1": "M1", "2": "M1+M2", "3": "M4+M1"} for key in ("vsimm", "ao_vsimm", "vsimm_as_printed")}
    _plot({"runs": 1, "scenarios": {"S1": {"filters": {"fsimm": series}, "active_groups_run0": groups}}}, tmp_path)
    fig = figures[1]  # the acceleration RMSE's figure first
    (ax,) = fig.axes
    legend = ax.get_legend().get_window_extent(FigureCanvasAgg(fig).get_renderer())
    assert legend.x0 >= ax.get_window_extent().x1 and ax.get_ylabel() == "active model group"


def test_the_map_legend_names_truth_tracks_sites_and_origin_below_the_axes(tmp_path: Path,
                                                                            figures: list[Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from fedtrack.fusion_center.mtt.earthmap import plot_map
    from fedtrack.geodetic import FrameConfig

    tracks, truth = scene(tmp_path, targets=2)
    plot_map(tracks, truth, FrameConfig((48.0, 2.0, 0.0), {"r1": (48.01, 2.01, 100.0)}), tmp_path / "m.png",
             label="mtt-federated")
    fig = figures[0]
    (ax,) = fig.axes
    assert legend_texts(ax) == ["truth (2 aircraft)", "confirmed tracks (2), a colour each", "sensor sites",
                                "frame origin"]
    legend = ax.get_legend().get_window_extent(FigureCanvasAgg(fig).get_renderer())
    assert legend.y1 <= ax.get_window_extent().y0


def test_the_demo_plot_names_the_algorithm_and_marks_maneuvers_in_legends_below_the_axes(
        tmp_path: Path, figures: list[Any]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from fedtrack.deploy.report import plot
    from fedtrack.deploy.settings import load_settings

    write_lines(tmp_path / "truth.jsonl", [{"t": float(k), "x": 100.0 * k, "y": 0.0} for k in range(40)])
    write_lines(tmp_path / "measurements.jsonl", [{"t": float(k), "sensor": "1", "z": [100.0 * k + 5, 3.0]}
                                                  for k in range(40)])
    write_lines(tmp_path / "tracks.jsonl", [{"t": float(k), "x": [100.0 * k, 100.0, 1.0, 0.0], "model": "cv",
                                             "event": "onset" if k in (32, 33) else None} for k in range(40)])
    assert plot(tmp_path, load_settings(None), "fedtrack demo") == tmp_path / "tracks.png"
    (fig,) = figures
    assert fig._suptitle.get_text() == "fedtrack demo: FVDIE (federated), scenario 1, 0 sensors: tracks.jsonl"
    renderer = FigureCanvasAgg(fig).get_renderer()
    for ax in fig.axes:
        assert ax.get_legend().get_window_extent(renderer).y1 <= ax.get_window_extent(renderer).y0
    texts = legend_texts(fig.axes[1])
    assert texts.count("true maneuver") == 1 and texts.count("maneuver detected") == 1


def test_a_launch_summary_names_its_algorithm(tmp_path: Path) -> None:
    """The recorder's pictures carry no ``algorithm``: every live multi-target run's summary.json said
    ``"algorithm": null`` (before tour57) though ``[multitarget] algorithm`` names it (the plot's title did)."""
    from fedtrack.deploy.multitarget import SCENARIO_DIR, finish_multitarget
    from fedtrack.deploy.report import LaunchReport
    from fedtrack.deploy.settings import load_settings

    tracks, truth = scene(tmp_path, targets=2)
    write_lines(tracks, [{k: v for k, v in json.loads(x).items() if k not in ("algorithm", "detector")}
                         for x in tracks.read_text().splitlines()])  # as the recorder's export writes them
    (tmp_path / SCENARIO_DIR).mkdir()
    truth.rename(tmp_path / SCENARIO_DIR / "truth.jsonl")
    config = tmp_path / "config.toml"
    config.write_text('[multitarget]\nalgorithm = "mtt-decentralized"\ntargets = 2\nsensors = "pos:1.0"\n')
    finish_multitarget(tmp_path, LaunchReport(), "fedtrack launch", load_settings(config))
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["algorithm"] == "mtt-decentralized" and summary["pictures"] == 20


def test_a_region_launch_draws_its_regions_in_tracks_png(tmp_path: Path, figures: list[Any]) -> None:
    """``launch`` of a ``[multitarget]`` config with ``[regions]``: its ``tracks.png`` has the borders
    (in-process: the launcher's finish over the files a run leaves)."""
    from fedtrack.deploy.multitarget import SCENARIO_DIR, finish_multitarget
    from fedtrack.deploy.report import LaunchReport
    from fedtrack.deploy.settings import load_settings

    tracks, truth = scene(tmp_path, targets=2)
    (tmp_path / SCENARIO_DIR).mkdir()
    truth.rename(tmp_path / SCENARIO_DIR / "truth.jsonl")
    config = tmp_path / "config.toml"
    config.write_text('[deployment]\nname = "plots"\n\n[multitarget]\nalgorithm = "mtt-federated"\ntargets = 2\n'
                      'sensors = "pos:1.0"\nduration = 20.0\n\n[regions]\nmargin = 50.0\n'
                      "grid = {origin = [-200.0, -200.0], cell = [200.0, 500.0], nx = 2, ny = 1}\n")
    finish_multitarget(tmp_path, LaunchReport(), "fedtrack launch", load_settings(config))
    ax = figures[0].axes[0]
    assert "region borders (2)" in legend_texts(ax) and (tmp_path / "tracks.png").is_file()
