"""Each centre of ``fedtrack bench scale`` measured in its own process (issue 27's load bar).

The in-process bench (:class:`ShardedCentre`) runs every region's centre in one process, in turn,
with the local trackers between their reports, and times each centre object there: a small
centre's fixed part of a report pays for the caches the other work left cold. A deployment runs
each centre as its own process (``fedtrack serve mtt-centre --region ID``). So the bench records
each region centre's calls as they are made (:meth:`ShardedCentre.record`: its sub-reports with the
hand-overs they sent out, the hand-overs it took over, the sensors dropped) and the pictures made
of it, each centre's to its own file (:class:`Recording`), and replays every file in a fresh
process (``python -m fedtrack.benchmarks.centre_process``, :func:`main`) which builds the centre
as ``serve mtt-centre`` does (:func:`service_from_args` of a config file holding the run's regions
as ``[regions]`` polygons, the grid's cells to the bit; no Zenoh session is opened; the one region
also as the unsharded centre, ``serve mtt-centre`` without ``--region``, on its full reports) and
measures there (:class:`CentreReplay`):

* the CPU seconds (``time.process_time()``) around each call alone, by kind: not the reading of
  the recording, the imports or the building of the service;
* the process's RSS (``VmRSS``) after the building, before the first call, and its peak from then
  on (``VmHWM``, reset then; not ``ru_maxrss``, which holds the bench's own peak: :func:`replay`):
  the centre's own memory is the difference.

Every replay must give the in-process run's pictures to the bit: each picture's tracks are
hashed row by row (:func:`picture_rows`), the regions' rows of a picture put together in
increasing id and compared with the in-process union picture's (:func:`check_pictures`), and
every sub-report's hand-overs out with the recorded ones; a difference stops the bench.

:func:`measure` replays in rounds, each round the one region (its region centre, then the
unsharded centre) and then every region of the other runs, so that each ratio is taken within a
round, against that round's one region, and the machine's drift over minutes falls on both
sides; the figures are the means over the rounds with their standard errors.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import pickle
import resource
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from fedtrack.fusion_center.mtt.engines import PictureTracks, TrackToTrackEngine
from fedtrack.fusion_center.mtt.regional import RegionEngine
from fedtrack.fusion_center.mtt.shards import ShardedCentre
from fedtrack.local_filters.regions import Regions, load_regions

KINDS = ("answer", "take_over", "drop", "picture")  # the calls made on a region centre
Rows = list[tuple[int, bytes]]  # a picture's tracks: (id, the digest of its row), in increasing id
CHILD_TIMEOUT_S = 1800.0  # one centre's replay (the 10-minute run's one region: about 20 CPU s)


class ReplayDiffers(RuntimeError):
    """A replayed centre did not do what the recorded one did."""


def picture_rows(p: PictureTracks) -> Rows:
    """Each track of a picture as its id and a digest of its whole row (state, covariance, confirmation,
    sensors, model, maneuver, existence), to the bit."""
    out: Rows = []
    for k, cid in enumerate(p.ids):
        h = hashlib.blake2b(digest_size=16)
        h.update(np.asarray(p.x[k], dtype=np.float64).tobytes())
        h.update(np.asarray(p.P[k], dtype=np.float64).tobytes())
        h.update(repr((bool(p.confirmed[k]), tuple(p.sensors[k]), str(p.models[k]))).encode())
        if p.maneuver is not None:
            h.update(np.asarray(p.maneuver[k]).tobytes())
        if p.existence is not None:
            h.update(np.float64(p.existence[k]).tobytes())
        out.append((int(cid), h.digest()))
    return out


def picture_digest(rows: Rows) -> bytes:
    """One digest of a picture's rows (in the order given)."""
    h = hashlib.blake2b(digest_size=16)
    for cid, row in rows:
        h.update(cid.to_bytes(8, "little", signed=True))
        h.update(row)
    return h.digest()


# ---------------------------------------------------------------- the recording (the bench's process)

@dataclass
class Recording:
    """One run's region centres' calls, each centre's streamed to ``folder / region-<r>.calls`` (pickled
    one by one: the calls of a picture period are kept in memory only until the picture), and the
    digests of the run's pictures (:func:`picture_rows` of the in-process union picture)."""

    folder: Path
    centre: ShardedCentre
    digests: list[bytes] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        self.calls = self.centre.record()
        self.files: list[IO[bytes]] = [self.path(r).open("wb") for r in range(len(self.calls))]

    def path(self, r: int) -> Path:
        return self.folder / f"region-{r}.calls"

    def flush(self) -> None:
        for calls, fh in zip(self.calls, self.files):
            for call in calls:
                pickle.dump(call, fh, protocol=pickle.HIGHEST_PROTOCOL)
            calls.clear()

    def picture(self, T: float, tracks: PictureTracks) -> None:
        """The calls so far, then the picture at ``T`` (every centre's part of it)."""
        self.flush()
        for fh in self.files:
            pickle.dump(("picture", T), fh, protocol=pickle.HIGHEST_PROTOCOL)
        self.digests.append(picture_digest(picture_rows(tracks)))

    def close(self) -> None:
        self.flush()
        for fh in self.files:
            fh.close()
        self.centre.calls = None


def read_calls(path: Path) -> Iterator[tuple[Any, ...]]:
    """The calls of a recording file, one at a time."""
    with path.open("rb") as fh:
        while True:
            try:
                yield pickle.load(fh)
            except EOFError:
                return


def regions_config(base: Path, regions: Regions, out: Path) -> Path:
    """``base`` (the run's config file) with ``regions`` as ``[regions]`` polygons (each cell's corners as
    Python's shortest round-trip repr: the loaded regions are these to the bit, checked)."""
    lines = [base.read_text(), "", "[regions]", f"margin = {float(regions.margin)!r}"]
    for rid, corners in zip(regions.ids, regions.vertices.tolist()):
        points = ", ".join(f"[{x!r}, {y!r}]" for x, y in corners)
        lines += ["", "[[regions.polygon]]", f'id = "{rid}"', f"points = [{points}]"]
    out.write_text("\n".join(lines) + "\n")
    loaded = load_regions(out)
    if (loaded is None or loaded.ids != regions.ids or loaded.margin != regions.margin
            or not np.array_equal(loaded.vertices, regions.vertices)):
        raise ReplayDiffers(f"{out}: its [regions] are not the run's regions")
    return out


# ---------------------------------------------------------------- the replay (a centre's own process)

@dataclass
class CentreReplay:
    """A centre as ``serve mtt-centre`` builds it (its engine: a :class:`RegionEngine` with ``--region``,
    else the unsharded :class:`TrackToTrackEngine`), fed recorded calls one at a time, each timed."""

    engine: RegionEngine | TrackToTrackEngine
    cpu_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(KINDS, 0.0))
    count: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))

    def call(self, entry: tuple[Any, ...]) -> PictureTracks | None:
        """One recorded call (CPU seconds around it alone); returns the picture of a picture call. Raises
        :class:`ReplayDiffers` when a sub-report's hand-overs out are not the recorded ones."""
        kind, args = entry[0], entry[1:]
        if kind not in KINDS:
            raise ReplayDiffers(f"unknown call {kind!r}")
        start = time.process_time()
        out = self._do(kind, args)
        self.cpu_s[kind] += time.process_time() - start
        self.count[kind] += 1
        if kind == "answer":
            moved = [(o, k, h.id) for o, k, h in out]
            if moved != args[2]:
                raise ReplayDiffers(f"report {self.count[kind]}: hand-overs out {moved}, recorded {args[2]}")
            return None
        return out if kind == "picture" else None

    def _do(self, kind: str, args: tuple[Any, ...]) -> Any:
        engine = self.engine
        if isinstance(engine, RegionEngine):
            if kind == "answer":
                return engine.region.answer(args[0], args[1])[1]
            if kind == "take_over":
                return engine.take_over(args[0])
            if kind == "drop":
                return engine.region.drop_sensor(*args)
            return engine.picture(args[0])
        if kind == "answer":  # the one region's sub-report is the whole report, no row elsewhere
            if args[1].any():
                raise ReplayDiffers("the unsharded centre got a sub-report with rows held elsewhere")
            engine.fuse(args[0])
            return []
        if kind == "take_over":
            raise ReplayDiffers("the unsharded centre got a hand-over")
        if kind == "drop":
            return None if engine.centre is None else engine.centre.drop_sensor(*args)
        return engine.picture(args[0])


def status_kb(name: str) -> int:
    """A size of this process now [KiB] from ``/proc/self/status`` (``VmRSS``, ``VmHWM``)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{name}:"):
            return int(line.split()[1])
    raise OSError(f"/proc/self/status has no {name}")


def reset_peak() -> None:
    """Set this process's peak RSS (``VmHWM``) to its RSS now (``/proc/self/clear_refs``, Linux 4.0+)."""
    Path("/proc/self/clear_refs").write_text("5")


def replay(engine: RegionEngine | TrackToTrackEngine, calls: Iterable[tuple[Any, ...]]) -> dict[str, Any]:
    """Feed ``calls`` to ``engine``: the CPU seconds and count of each kind, each picture's rows
    (:func:`picture_rows`), the RSS before the first call and the peak from then on [KiB].

    The peak is ``VmHWM``, reset before the first call (:func:`reset_peak`): ``ru_maxrss``
    (``getrusage``) of a process started by another holds the starting process's peak (the kernel
    keeps the high-water mark of the memory image that ``exec`` replaced: the forking bench's; a
    480 MB parent gave its child 498 MB against a ``VmHWM`` of 11 MB), reported beside it as
    ``ru_maxrss_kb``."""
    rep = CentreReplay(engine)
    reset_peak()
    before = status_kb("VmRSS")
    pictures: list[Rows] = []
    for entry in calls:
        picture = rep.call(entry)
        if picture is not None:
            pictures.append(picture_rows(picture))
    return {"cpu_s": rep.cpu_s, "count": rep.count, "pictures": pictures, "rss_before_kb": before,
            "rss_peak_kb": status_kb("VmHWM"), "ru_maxrss_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}


def main(argv: list[str]) -> int:
    """The centre process: ``RECORDING OUT`` then ``serve mtt-centre``'s arguments."""
    parser = argparse.ArgumentParser(prog="python -m fedtrack.benchmarks.centre_process",
                                     description="one centre of bench scale replayed on its recorded calls")
    parser.add_argument("recording", type=Path, help="the centre's recorded calls (Recording)")
    parser.add_argument("out", type=Path, help="where the measurements go (pickled)")
    args, service_args = parser.parse_known_args(argv)
    from fedtrack.fusion_center.mtt.service import service_from_args  # the live centre's imports, as it runs

    engine = service_from_args(service_args).engine
    assert isinstance(engine, (RegionEngine, TrackToTrackEngine))
    result = replay(engine, read_calls(args.recording))
    with args.out.open("wb") as fh:
        pickle.dump(result, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return 0


# ---------------------------------------------------------------- the rounds (the bench's process)

@dataclass(frozen=True)
class Centre:
    """A centre to replay: run ``n``'s region ``r``; ``r`` None: the unsharded centre on the one region's calls."""

    n: int
    r: int | None

    @property
    def name(self) -> str:
        return f"{self.n} regions, region {self.r}" if self.r is not None else "the unsharded centre"


def spawn(centre: Centre, recording: Path, config: Path, region: str | None, dim: int, out: Path) -> dict[str, Any]:
    """One centre's replay in a fresh process (bounded by ``CHILD_TIMEOUT_S``)."""
    cmd = [sys.executable, "-m", "fedtrack.benchmarks.centre_process", str(recording), str(out),
           "--config", str(config), "--dim", str(dim), "--id", "bench"]
    cmd += [] if region is None else ["--region", region]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=CHILD_TIMEOUT_S)
    if proc.returncode != 0:
        raise ReplayDiffers(f"{centre.name}: its replay process failed: {proc.stderr[-3000:]}")
    with out.open("rb") as fh:
        return pickle.load(fh)


def check_pictures(name: str, parts: list[list[Rows]], digests: list[bytes]) -> None:
    """The regions' replayed pictures (per region, per picture) put together equal the in-process ones."""
    if any(len(p) != len(digests) for p in parts):
        raise ReplayDiffers(f"{name}: {[len(p) for p in parts]} pictures replayed, {len(digests)} made in process")
    for k, digest in enumerate(digests):
        rows = sorted((row for p in parts for row in p[k]), key=lambda row: row[0])
        if picture_digest(rows) != digest:
            raise ReplayDiffers(f"{name}: picture {k} differs from the in-process run's")


def mean_se(values: list[float]) -> tuple[float, float | None]:
    """The mean and its standard error (None from one value)."""
    a = np.asarray(values, dtype=float)
    return float(a.mean()), (float(a.std(ddof=1) / math.sqrt(a.size)) if a.size > 1 else None)


def centre_figures(results: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per round: a centre's CPU seconds (all calls; the reports and hand-overs alone; the pictures), its
    peak RSS and its own memory (peak less the RSS before the first call) [MB]."""
    cpu = [sum(r["cpu_s"].values()) for r in results]
    return {"cpu_s": cpu, "calls_cpu_s": [c - r["cpu_s"]["picture"] for c, r in zip(cpu, results)],
            "picture_cpu_s": [r["cpu_s"]["picture"] for r in results],
            "rss_before_mb": [r["rss_before_kb"] / 1024 for r in results],
            "rss_peak_mb": [r["rss_peak_kb"] / 1024 for r in results],
            "own_rss_mb": [(r["rss_peak_kb"] - r["rss_before_kb"]) / 1024 for r in results]}


def ratios(parts: list[list[float]], one: list[float]) -> tuple[float, float | None, list[float]]:
    """The largest part (by its mean over the rounds) over ``one``, round by round: mean, SE, the rounds'."""
    largest = int(np.argmax([np.mean(p) for p in parts]))
    per = [a / b for a, b in zip(parts[largest], one)]
    return (*mean_se(per), per)


def measure(runs: dict[int, tuple[Recording, Path, Regions]], dim: int, rounds: int, folder: Path,
            progress: Any = None) -> dict[str, Any]:
    """Every centre of ``runs`` (region count -> its recording, config file and regions; 1 among them)
    replayed in its own process, ``rounds`` times in turn (module docstring); the pictures checked."""
    order = [Centre(1, 0), Centre(1, None)] + [Centre(n, r) for n in sorted(runs) if n > 1 for r in range(n)]
    results: dict[Centre, list[dict[str, Any]]] = {c: [] for c in order}
    for _ in range(rounds):
        for c in order:
            recording, config, regions = runs[c.n]
            res = spawn(c, recording.path(c.r or 0), config, None if c.r is None else regions.ids[c.r], dim,
                        folder / "result.pkl")
            if c.r is None:
                check_pictures(c.name, [res["pictures"]], recording.digests)
            results[c].append(res)
            if progress is not None:
                progress.update()
        for n, (recording, _, _) in runs.items():
            check_pictures(f"{n} regions", [results[Centre(n, r)][-1]["pictures"] for r in range(n)], recording.digests)
    for res in results.values():
        for r in res:
            del r["pictures"]
    one = centre_figures(results[Centre(1, 0)])
    unsharded = centre_figures(results[Centre(1, None)])
    out: dict[str, Any] = {"rounds": rounds, "unsharded": {}, "runs": {}}
    for key, values in unsharded.items():
        out["unsharded"][key], out["unsharded"][f"{key}_se"] = mean_se(values)
    for n in sorted(runs):
        figs = [centre_figures(results[Centre(n, r)]) for r in range(n)]
        row: dict[str, Any] = {}
        for key in figs[0]:
            stats = [mean_se(f[key]) for f in figs]
            row[key], row[f"{key}_se"] = [m for m, _ in stats], [s for _, s in stats]
        for name, key, base in (("busiest_vs_one", "cpu_s", one), ("busiest_calls_vs_one", "calls_cpu_s", one),
                                ("busiest_vs_unsharded", "cpu_s", unsharded),
                                ("largest_rss_vs_one", "rss_peak_mb", one),
                                ("largest_own_rss_vs_one", "own_rss_mb", one)):
            row[name], row[f"{name}_se"], row[f"{name}_rounds"] = ratios([f[key] for f in figs], base[key])
        row["busiest"] = int(np.argmax(row["cpu_s"]))
        out["runs"][n] = row
    return out
