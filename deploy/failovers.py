"""Failovers and router outages as a launcher sees them: from the centres' primary tokens
(``alive/mtt-primary/<scope>/<instance>``), the router tokens (``alive/router/*``) and the times of
each scope's pictures. Pure bookkeeping, no Zenoh: :class:`fedtrack.deploy.monitor.Monitor` calls it
under its lock and logs the lines it returns; ``summary.json`` lists ``failovers`` and
``router_outages`` (docs/deploy.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from fedtrack.fusion_center.mtt.failover.standby import CENTRE_TOKENS_KEPT, SILENT_S


@dataclass
class Failover:
    """A centre's primary token went (``lost_ns``, wall clock), its standby claimed it
    (``took_over_ns``), and the first picture of its scope arrived after that (``covered_ns``)."""

    scope: str
    lost_ns: int
    took_over_ns: int | None = None
    covered_ns: int | None = None
    instance: str = ""  # the primary token that went: back unchanged, its primary lived (a router outage)

    def summary(self, epoch: float | None, speed: float, scan_s: float) -> dict[str, Any]:
        """The report's entry: times in seconds after the loss, the loss in scenario seconds, and
        the time to the next picture in scans of ``scan_s`` scenario seconds."""
        def after(ns: int | None) -> float | None:
            return None if ns is None else (ns - self.lost_ns) / 1e9
        covered = after(self.covered_ns)
        return {"scope": self.scope, "lost_at": self.lost_ns / 1e9,
                "t": None if epoch is None else (self.lost_ns / 1e9 - epoch) * speed,
                "took_over_after_s": after(self.took_over_ns), "covered_after_s": covered,
                "scans": None if covered is None else covered * speed / scan_s}


@dataclass
class RouterOutage:
    """The launcher's link to its router went (``lost_ns``, wall clock: the last router token gone)
    and came back (``back_ns``); every token went with it, each region's primary token among them."""

    lost_ns: int
    back_ns: int | None = None

    def summary(self, epoch: float | None, speed: float) -> dict[str, Any]:
        """The report's entry: the loss in scenario seconds, the outage in seconds."""
        return {"lost_at": self.lost_ns / 1e9, "t": None if epoch is None else (self.lost_ns / 1e9 - epoch) * speed,
                "back_after_s": None if self.back_ns is None else (self.back_ns - self.lost_ns) / 1e9}


@dataclass
class FailoverWatch:
    """The failovers of the deployment's centres (``scopes``: :func:`fedtrack.deploy.plan.failover_scopes`;
    another scope's tokens are ignored) and the outages of the launcher's router link. ``stopping``:
    the launcher is stopping everything, and tokens going now are no failover."""

    scopes: frozenset[str]
    failovers: list[Failover] = field(default_factory=list)
    outages: list[RouterOutage] = field(default_factory=list)
    primaries: dict[str, set[str]] = field(default_factory=dict)  # scope -> the instances holding its token
    pictured: dict[str, int] = field(default_factory=dict)  # scope -> wall-clock ns of its latest picture
    routers: set[str] = field(default_factory=set)  # router tokens seen
    stopping: bool = False
    tokens_ignored: int = 0  # primary tokens not followed: beyond CENTRE_TOKENS_KEPT of a scope

    def primary_token(self, scope: str, instance: str, gone: bool, now: int) -> str | None:
        """A centre's primary token went (its primary died: the last of its scope's) or was claimed.
                A claim ends the failover of its scope: by the token that went, back unchanged, it was no
                failover (its primary lived; the link to the router went, taking every token with it: a killed
                router made one failover per region); by another, its standby took over. A claim later than
                every token standing, the scope's pictures silent, is a take-over from a primary whose token
                stands (frozen: the standby's silence rule, ``SILENT_S``; silent here for half of it, the rest
                for the links' delays): a failover from the scope's last picture. A second primary's token,
                withdrawn when it steps down, is none. A token of a scope the deployment has no centre of is
                ignored: any ``fusion`` identity may declare one, and each declared and withdrawn was a failover
                in the report, for good. A token that would be one more than ``CENTRE_TOKENS_KEPT`` of its
                scope is not followed (counted ``tokens_ignored``), nor is its going: each claim copies the
                scope's tokens, and 20,000 forged ones cost the monitor 2.7 s of CPU.
        Returns the line to log, if any."""
        if self.stopping or scope not in self.scopes:  # a token of no centre of its: forged, kept nowhere
            return None
        holders = self.primaries.setdefault(scope, set())
        if instance not in holders and len(holders) >= CENTRE_TOKENS_KEPT:
            self.tokens_ignored += int(not gone)
            return None
        if gone:
            holders.discard(instance)
            if holders:
                return None
            self.failovers.append(Failover(scope, now, instance=instance))
            return f"the primary centre of {scope} is gone"
        standing, quiet = set(holders), now - self.pictured.get(scope, now) >= SILENT_S / 2 * 1e9  # links' delay
        holders.add(instance)
        open_ = [f for f in self.failovers if f.scope == scope and f.took_over_ns is None]
        lines = []
        for f in open_:
            if f.instance == instance:  # the same primary: its link came back (a router outage)
                self.failovers.remove(f)
                lines.append(f"the primary centre of {scope} is back (its link went, not the centre)")
                continue
            f.took_over_ns = now
            lines.append(f"a standby took over {scope} after {(now - f.lost_ns) / 1e6:.0f} ms")
        if not open_ and standing and quiet and all(instance > other for other in standing):
            self.failovers.append(Failover(scope, self.pictured[scope], now, instance=instance))
            lines.append(f"a standby took over {scope} from a silent primary")
        return "; ".join(lines) or None

    def router_token(self, name: str, gone: bool, now: int) -> str | None:
        """The last router token went (the launcher's link to its router: a router outage) or one came
        back (the outage's end); the line to log, if any."""
        if gone:
            self.routers.discard(name)
            if not self.routers and not self.stopping and not any(o.back_ns is None for o in self.outages):
                self.outages.append(RouterOutage(now))
                return "the router is gone"
            return None
        self.routers.add(name)
        lines = []
        for o in self.outages:
            if o.back_ns is None:
                o.back_ns = now
                lines.append(f"the router is back after {(now - o.lost_ns) / 1e9:.2f} s")
        return "; ".join(lines) or None

    def covered(self, scope: str, now: int) -> None:
        """A picture of ``scope`` arrived: the first after a takeover ends that failover."""
        self.pictured[scope] = now
        for f in self.failovers:
            if f.scope == scope and f.took_over_ns is not None and f.covered_ns is None:
                f.covered_ns = now
