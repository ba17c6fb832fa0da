"""Where and whether the vehicle may rejoin its route (docs/design.md, "Checked holds", "Leaving a hold"): the item
to fly to, the leg and the turns onto it checked against the static world, and the route from there against the
traffic. Resuming never flies an unchecked leg."""

from __future__ import annotations

import numpy as np

from companion.replanning.context import ReplanContext
from companion.replanning.guard import first_breach
from companion.replanning.holds import HOLD_MARGIN_M
from companion.replanning.modes import ModeControl
from companion.replanning.motion import VehicleMotion
from companion.replanning.prediction import Prediction
from companion.replanning.replan import via_items
from companion.replanning.swap import MissionSwap
from planner.trajectory.checks import nearest_obstacle

JOIN_LATENCY_S = 1.0  # vehicle seconds between choosing the item to join and the autopilot flying to it
RESUME_HORIZON_S = 20.0  # vehicle seconds of the path flown on resuming that are checked
# m beyond d_coll that what a plane flies on resuming must clear, as a hold's: with 5 m, a plane resumed on ArduPlane
# SITL (under load) came 7.2 m from a cylinder the check had passed at 15 m; with 10 m the simulator's plane once
# circled through 120 replans, every route planned from its circle 19.1-20.0 m from a cylinder (before holds took
# circles a little short of their margin and kept the route where it kept the traffic further; docs/design.md)
RESUME_MARGIN_M = HOLD_MARGIN_M


class RejoinChecks:
    """The checks before a vehicle is sent back to (or along) its live route."""

    def __init__(self, ctx: ReplanContext, motion: VehicleMotion, prediction: Prediction, modes: ModeControl,
                 swap: MissionSwap) -> None:
        self.ctx, self.motion, self.prediction, self.modes, self.swap = ctx, motion, prediction, modes, swap

    def join_seq(self, first_new_seq: int) -> int:
        """The commit point's item, or the next one if the vehicle is already past the commit point (it
        would otherwise turn back for it)."""
        route, position = self.swap.route, self.ctx.state.position
        seqs, pts = route.seqs, route.points
        k = int(np.flatnonzero(seqs == first_new_seq)[0])
        if position is None or k + 1 >= len(seqs):
            return first_new_seq
        ahead = pts[k + 1] - pts[k]
        passed = float(np.dot(position - pts[k], ahead)) > self.ctx.scenario.vehicle.acceptance_radius * \
            float(np.linalg.norm(ahead))
        if passed:
            self.ctx.events.log("commit_point_passed", joining=int(seqs[k + 1]))
            return int(seqs[k + 1])
        return first_new_seq

    def clear_from(self, seq: int, delays: np.ndarray | None = None) -> bool:
        """Whether the mission from item ``seq`` on, flown from where the vehicle is now (and, if it is held,
        from whenever it may be back on it: :meth:`ModeControl.rejoin_delays`, or ``delays`` vehicle seconds), keeps
        every threat at d_coll or more (the plan was checked from the commit point at its ETA; this checks the
        join)."""
        state, route = self.ctx.state, self.swap.route
        if state.position is None:
            return True
        now = state.now()
        ahead, _ = route.remaining(state.position, max(seq, int(route.seqs[0])))
        worst = self.prediction.closest(ahead, now, self.prediction.threats(now),
                                        self.modes.rejoin_delays() if delays is None else delays)
        if worst is not None:
            self.ctx.events.log("join_check", seq=seq, threat=worst.threat_id,
                                separation_m=round(worst.separation, 1), in_s=round(worst.t - now, 1))
        return worst is None or worst.separation >= self.ctx.d_coll

    def route_blocked(self, seq: int) -> tuple[float, str | None] | None:
        """(clearance, obstacle) when a leg of the mission from item ``seq`` on comes within d_coll of a static
        obstacle (a route that was never checked: an edited PLAN.json, a ground station's mission); else None."""
        route = self.swap.route
        ahead = route.points[route.seqs >= seq]
        if len(ahead) < 2:
            return None
        seg = np.diff(ahead, axis=0)
        n = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / 5.0).astype(int), 1)
        pts = np.vstack([a + np.outer(np.arange(k + 1) / k, s) for a, s, k in zip(ahead[:-1], seg, n, strict=True)])
        clearance, worst = nearest_obstacle(pts, self.ctx.scenario.environment)
        return None if clearance >= self.ctx.d_coll else (clearance, worst)

    def ahead_seq(self, seq: int) -> int:
        """The first route item from ``seq`` on that a plane can fly to from where it is: not passed along the
        route (beyond it along the leg k -> k+1), not behind it (against its velocity) and not within two wide
        turns plus a second of flight (what it cannot turn onto without a loop). Resumed towards such an item,
        ArduPlane loops back round through whatever is beside it: on SITL, after a hold beside item 5, 33 m into a
        cylinder. The goal is always kept, and so is a via of the scenario (the route must pass through it: a join
        that cannot fly to it safely is refused by :meth:`leg_blocked`, and the vehicle replanned through it). A
        copter keeps ``seq``."""
        state = self.ctx.state
        if state.position is None or not self.ctx.profile.hold_circles:
            return seq
        seqs, pts = self.swap.route.seqs, self.swap.route.points
        vias = {s for s, _ in via_items(self.swap.route, self.ctx.scenario.vias)}
        p, v = state.position[:2], state.velocity
        near = 2.0 * self.motion.wide_turn_radius(state.groundspeed) + max(state.groundspeed, 1.0) * JOIN_LATENCY_S
        moving = float(np.linalg.norm(v)) > 1.0
        target = seq
        for k in np.flatnonzero((seqs >= seq) & (seqs < self.swap.goal_seq)):
            if int(seqs[k]) in vias:
                break
            to = pts[k, :2] - p
            passed = k + 1 < len(seqs) and float(np.dot(p - pts[k, :2], pts[k + 1, :2] - pts[k, :2])) > 0
            behind = moving and float(np.dot(to, v)) <= 0.0
            if not (passed or behind or float(np.linalg.norm(to)) < near) or k + 1 >= len(seqs):
                break
            target = int(seqs[k + 1])
        if target != seq:
            self.ctx.events.log("join_ahead", behind=seq, joining=target)
        return target

    def leg_blocked(self, seq: int, margin_m: float = RESUME_MARGIN_M) -> tuple[float, str | None] | None:
        """(clearance, obstacle) when what AUTO flies on resuming at item ``seq`` comes too close to a static
        obstacle: the straight leg from the vehicle to the item, or the path a plane flies onto it and on
        (:meth:`VehicleMotion.flown_paths`, 20 s, straight at the item from where its turn ends, each turn it may
        make, each item taken as early as the autopilot may), within d_coll + ``margin_m``; None when both are
        clear."""
        state, route = self.ctx.state, self.swap.route
        if state.position is None:
            return None
        hit = np.flatnonzero(route.seqs >= seq)
        if not hit.size:
            return None
        target = route.points[hit[0]]
        leg = np.linspace(state.position, target, max(int(np.linalg.norm(target - state.position) / 5.0), 1) + 1)
        env = self.ctx.scenario.environment
        need = self.ctx.d_coll + margin_m
        clearance, worst = nearest_obstacle(leg, env)
        if clearance < need:
            return clearance, worst
        if self.ctx.profile.hold_circles and float(np.linalg.norm(state.velocity)) > 1.0:
            # AUTO flies to the item straight from wherever the plane ends its turn towards it (no leg to hold to),
            # so every path it may fly is checked (flown_paths): resumed 101 m from its item, SITL's plane took it
            # early and cut to the next leg 6.5 m from a cylinder the path taking it at its 20 m cleared by 20.3 m
            wide = self.motion.wide_turn_radius(state.groundspeed)
            for position, velocity in self.modes.rolling_out():
                behind = float(np.dot(target[:2] - position[:2], velocity[:2])) < 0.0
                for path in self.motion.flown_paths(position, velocity, position, route.points[hit[0]:],
                                                    wide, RESUME_HORIZON_S, direct=True, behind=behind):
                    # by the margin too: the model starts wings level, and a plane resumed from a hold circle is
                    # banked (on the simulator, resumed 3 s into its circle, a path predicted clear came 6.3 m from a
                    # cylinder)
                    breach = first_breach(path, env, need)
                    if breach is not None:
                        return breach.clearance_m, breach.obstacle
        return None
