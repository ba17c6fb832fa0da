"""The replanner's mission swap (docs/design.md, "Live replanning"): the mission verified on the vehicle, a new one
uploaded while it flies (held first when it could step into a half-written item), verified by readback, and the
active item moved with MISSION_CURRENT confirming it."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass

import numpy as np

from companion.mavlink.errors import CommandError, CompanionError, MissionUploadError, VehicleHolding
from companion.mavlink.items import MissionItem
from companion.mission import picture
from companion.mission.restore import restore_mission
from companion.replanning.context import ReplanContext
from companion.replanning.modes import ModeControl
from companion.replanning.motion import VehicleMotion
from companion.replanning.prediction import Prediction
from companion.replanning.replan import MissionRoute, ReplanRecord


@dataclass(frozen=True)
class LiveMission:
    """A mission verified on the vehicle, stored there from ``t`` (the event log's time of the record saying its
    readback matched) until the next one: ``reason`` says why (``"replan 2"``, ``"restored after replan 2"``),
    ``replan`` is that replan's number."""

    t: float
    reason: str
    items: tuple[MissionItem, ...]
    replan: int | None = None


class MissionSwap:
    """The live mission: ``route`` (its route points and items) and ``verified`` (every mission known verified on
    the vehicle, with the monotonic time its readback matched), changed only by :meth:`upload`; ``history`` the
    missions this swap stored (the first one, the supervisor's, is not among them)."""

    def __init__(self, ctx: ReplanContext, motion: VehicleMotion, prediction: Prediction, modes: ModeControl,
                 items: Sequence[MissionItem]) -> None:
        self.ctx, self.motion, self.prediction, self.modes = ctx, motion, prediction, modes
        self.route = MissionRoute.of(items, ctx.scenario.home)
        self.verified: list[tuple[float, list[MissionItem]]] = [(time.monotonic(), list(items))]
        self.history: list[LiveMission] = []
        self.upload_wall_s = 0.05  # running estimate of one verified upload (wall s)
        self.changing = False  # an upload or a restore is under way: the stored mission is in flux

    @property
    def goal_seq(self) -> int:
        return self.route.goal_seq

    @property
    def mission(self) -> list[MissionItem]:
        """The mission last verified on the vehicle."""
        return self.verified[-1][1]

    def remaining(self) -> tuple[np.ndarray, np.ndarray]:
        """The route still to fly from where the vehicle is (points, item numbers)."""
        state = self.ctx.state
        assert state.position is not None
        return self.route.remaining(state.position, max(state.current_seq, int(self.route.seqs[0])))

    def on_route(self) -> bool:
        """Flying the route (past the takeoff and the speed item): the start waypoint or later."""
        return int(self.route.seqs[0]) <= self.ctx.state.current_seq <= self.goal_seq

    def note_upload(self, seconds: float) -> None:
        """A verified upload of the whole mission took ``seconds`` (wall): the first guess for a replan's."""
        self.upload_wall_s = max(self.upload_wall_s, float(seconds))

    def guard_threshold_s(self) -> float:
        """Vehicle seconds before leaving its unchanged items below which a swap holds the vehicle first."""
        return self.ctx.cfg.guard_s + 2.0 * self.upload_wall_s * self.ctx.state.clock.rate

    def eta_leave_prefix(self, first_new_seq: int) -> float:
        """Vehicle seconds until it could step into an item at or after ``first_new_seq`` (being rewritten):
        when it completes item ``first_new_seq − 1``, or its active item if that is already being replaced.
        Pessimistic: the faster of cruise and ground speed, and ArduPlane's early waypoint switching."""
        state = self.ctx.state
        if state.position is None:
            return math.inf
        route, seqs = self.remaining()
        target = max(state.current_seq, first_new_seq - 1)
        hit = np.flatnonzero(seqs >= target)
        if not hit.size:
            return math.inf
        legs = np.linalg.norm(np.diff(route[:hit[0] + 1], axis=0), axis=1)
        return max(float(legs.sum()) - self.motion.switch_m(), 0.0) / max(self.prediction.speed, state.groundspeed,
                                                                           1.0)

    async def guarded(self, task: asyncio.Task, first_new_seq: int, threshold_s: float, reason: str,
                      rec: ReplanRecord, route_separation: float | None = None) -> None:
        """Wait for ``task`` (a plan or an upload) watching the vehicle meanwhile: hold it, saying ``reason``,
        once it could step into item ``first_new_seq`` or a later one within ``threshold_s`` of vehicle time
        while the task still runs (``route_separation``: see :meth:`ModeControl.hold`). On any exception (a cancel
        included) the task is cancelled first."""
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=0.01)
                if self.modes.holding is None and not task.done() and \
                        self.eta_leave_prefix(first_new_seq) < threshold_s:
                    await self.modes.hold(reason, route_separation)
                    rec.held = rec.held or self.modes.holding is not None
        except BaseException:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            raise

    async def upload(self, items: list[MissionItem], first_new_seq: int, rec: ReplanRecord) -> None:
        """:meth:`_upload`, with ``changing`` set meanwhile (the supervisor's readback after an outage waits for
        it: the stored list is being changed by us, and this upload's own readback proves what it holds)."""
        self.changing = True
        try:
            await self._upload(items, first_new_seq, rec)
        finally:
            self.changing = False

    async def _upload(self, items: list[MissionItem], first_new_seq: int, rec: ReplanRecord) -> None:
        """Upload ``items`` while the vehicle flies and verify them: the vehicle is held first where it would
        re-read its items during the upload, or could finish its active item before they are verified; a failed
        upload holds it and tries again, a refused or last one puts the last verified mission back (raising
        :class:`VehicleHolding` after the last). Verified, they are the live ``route``."""
        ctx, cfg, modes = self.ctx, self.ctx.cfg, self.modes
        if modes.holding is None and not ctx.profile.flies_copy_during_upload:
            await modes.hold("the vehicle would re-read its items from storage during the upload")
            rec.held = True
        elif modes.holding is None and self.eta_leave_prefix(first_new_seq) < self.guard_threshold_s():
            await modes.hold("the vehicle could finish its active item before the new mission is verified")
            rec.held = True
        for attempt in range(1, cfg.upload_attempts + 1):
            t0 = time.monotonic()
            # only what changed where the autopilot takes a partial write (ArduPilot), else the whole mission
            upload = asyncio.create_task(ctx.client.upload_changed_verified(items, self.mission), name="replan-upload")
            try:
                await self.guarded(upload, first_new_seq, cfg.guard_s,
                                   "upload not verified yet and the vehicle is about to leave its item", rec)
            except asyncio.CancelledError:
                # cancelled mid-upload (flight ended, Ctrl-C): the stored mission may be mixed, so hold first
                if modes.holding is None:
                    await asyncio.shield(modes.hold("cancelled during an upload: the stored mission may be mixed"))
                raise
            try:
                rec.upload_path = upload.result()
            except (CompanionError, TimeoutError) as e:
                ctx.events.log("replan_upload_failed", n=rec.n, attempt=attempt, error=str(e))
                if modes.holding is None:  # the stored mission may now be part old, part new
                    await modes.hold("upload failed: the stored mission may be mixed")
                    rec.held = True
                refused = isinstance(e, MissionUploadError) and e.refused
                if refused or attempt == cfg.upload_attempts:
                    # a refusal will likely come again: first put the last verified mission back, so that what
                    # is stored is verified while the vehicle holds and whatever happens next
                    restored, left_with = await restore_mission(ctx.client, ctx.events, self.mission)
                    if restored:
                        self.verified.append((time.monotonic(), list(self.mission)))
                        t = next((r["t"] for r in reversed(ctx.events.records) if r["event"] == "mission_restored"),
                                 ctx.events.records[-1]["t"])
                        self.history.append(LiveMission(t, f"restored after replan {rec.n}", tuple(self.mission),
                                                        rec.n))
                    if attempt == cfg.upload_attempts:
                        raise VehicleHolding(f"replan {rec.n}: no verified upload after {attempt} attempts ({e}); "
                                             f"{left_with}; the vehicle is holding") from e
                continue
            self.upload_wall_s = 0.7 * self.upload_wall_s + 0.3 * (time.monotonic() - t0)
            break
        self.route = MissionRoute.of(items, ctx.scenario.home)
        self.verified.append((time.monotonic(), list(items)))
        done = ctx.events.log("replan_verified", n=rec.n, items=len(items), first_new=first_new_seq)
        self.history.append(LiveMission(done["t"], f"replan {rec.n}", tuple(items), rec.n))
        ctx.events.log("mission", **picture.mission(items, ctx.scenario.home))

    async def set_current(self, seq: int, then: Callable[[], Awaitable[None]] | None = None) -> None:
        """DO_SET_MISSION_CURRENT and wait until MISSION_CURRENT shows it (the vehicle took it). ``then`` (a held
        vehicle's resume) runs as soon as the command is acknowledged, while that confirmation is on its way: it
        comes with the autopilot's next status message, a loop or more later (ArduPlane SITL at 10x: 10-20 ms)."""
        state = self.ctx.state
        with self.ctx.link.subscribe("MISSION_CURRENT", predicate=lambda m: m.seq == seq) as sub:
            await self.ctx.client.set_current(seq)
            if then is not None:
                state.current_seq = seq
                await then()
            try:
                await sub.get(2.0)
            except TimeoutError:
                raise CommandError(0, None, f"MISSION_CURRENT did not confirm item {seq}") from None
        state.current_seq = seq
        self.ctx.events.log("set_current", seq=seq)
