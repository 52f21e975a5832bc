"""What the Grasps folder says: the grasp dropdown's entries and the text about the listed
segment's plan, the selected grasp and its execution. Plain values in, markdown out; no viser.

Units shown: millimetres for positions and prismatic joints, degrees for revolute joints and
joint errors, epsilon (the grasp quality) as the planner computes it.
"""

from __future__ import annotations

import math

import numpy as np

from ...grasp.execute import ExecutionResult
from ...grasp.hands import Hand, get_hand
from ...grasp.robust import LIFT_TOP, RECHECK_TOP, ROBUST_QUANTILE, WIDEN_BELOW, Robustness, rank_robust
from ...grasp.state import LiftResult
from .state import SegmentGrasps

NO_PLAN = "_Select a segment, then plan grasps on it._"


def _joint_value(hand: Hand, name: str, value: float) -> str:
    """A joint value for people: degrees for revolute joints, millimetres for prismatic ones."""
    kind = next(j.kind for j in hand.model.joints if j.name == name)
    return f"{1000 * value:.1f} mm" if kind == "prismatic" else f"{math.degrees(value):.1f}°"


def _epsilon_text(epsilon: float) -> str:
    return f"{epsilon:.4f}" if epsilon > 0 else f"{epsilon:.4f} (no force closure)"


def _lift_text(lift: LiftResult | None) -> str:
    if lift is None:
        return "lift test not run"
    verdict = "**lifted** ✓" if lift.success else "**dropped** ✗"
    return f"{verdict} (rose {1000 * lift.rise:.0f} mm, slipped {1000 * lift.slip:.0f} mm)"


def _holds(r: Robustness) -> str:
    """``holds <n>/<samples>``: on how many sample completions a grasp still has force closure."""
    return f"holds {round(r.fraction * len(r.epsilons))}/{len(r.epsilons)}"


def _lifted(r: Robustness) -> str:
    """`` · lifted <n>/<tests>``: how many of its lift tests on the sample completions a grasp
    passed (one per sample and round; "" when it was not lifted on them)."""
    n = r.lift_tests
    return "" if r.lifted is None else f" · lifted {round(r.lifted * n)}/{n}"


def grasp_options(s: SegmentGrasps) -> dict[str, int]:
    """The Grasp dropdown's entries for ``s``: ``#<planner rank>  ε <epsilon>`` (``· lifts`` when
    the planner's lift check picked it up, ``· holds <n>/<samples>`` once ranked by robustness, and
    ``· lifted <m>/<samples>`` for the grasps lifted on the samples) ->
    index in ``s.grasps``, in the planner's order or,
    once ranked, most robust first. The number stays the planner's: it names the grasp's hand."""
    order = range(len(s.grasps)) if s.robustness is None else rank_robust(s.robustness, _lifts(s))
    options = {}
    for k in order:
        g = s.grasps[k]
        entry = f"#{k + 1}{' envelope' if _wider(s, k) else ''}  ε {g.epsilon:.3f}"
        entry += "" if g.force_closure else " (no closure)"
        entry += " · lifts" if g.lifted else ""
        if s.robustness is not None:
            entry += f" · {_holds(s.robustness[k])}{_lifted(s.robustness[k])}"
        options[entry] = k
    return options


def _wider(s: SegmentGrasps, k: int) -> bool:
    """Whether grasp ``k`` of ``s`` comes from the ranking's wider search on the grasp envelope."""
    return s.wider_from is not None and k >= s.wider_from


def _lifts(s: SegmentGrasps) -> list[LiftResult | None]:
    return [g.lift for g in s.grasps]


def _robustness_line(scores: list[Robustness], lifts: list[LiftResult | None], k: int) -> str:
    """Grasp ``k``'s robustness among ``scores``: its robust rank (after the planner's ``lifts``),
    on how many sample completions it holds, and its epsilon's lower quantile over them."""
    r = scores[k]
    rank = rank_robust(scores, lifts).index(k) + 1
    return (
        f"**Robustness**: rank **{rank}** of {len(scores)} · **{_holds(r)}** sample completions "
        f"({100 * r.fraction:.0f}%){_lifted(r)} · {100 * ROBUST_QUANTILE:.0f}% ε {r.epsilon_low:.4f}"
    )


def info_markdown(s: SegmentGrasps | None, real_capture: bool, selected: int | None) -> str:
    """The Grasps folder's text: the plan ``s`` of the listed segment (None: nothing planned), a
    note when the scene is a real capture (no ground truth), the ``selected`` grasp and its execution."""
    if s is None:
        return NO_PLAN
    n_fc = sum(g.force_closure for g in s.grasps)
    checked = [g.lift.success for g in s.grasps if g.lift is not None]
    lines = [
        f"**Segment {s.segment_id}** · {s.hand} on the {s.method} mesh · **{len(s.grasps)}** grasps "
        f"({n_fc} force closure"
        + (f", {sum(checked)} of {len(checked)} checked lift the mesh in simulation: first" if checked else "")
        + f") in {s.stats.seconds.get('total', 0.0):.1f} s"
    ]
    if s.grasps:
        best = max(g.epsilon for g in s.grasps)
        lines.append(f"Colour: ε from red (0) to green (ε = {best:.3f}, the best); grey: no force closure.")
    if s.robustness:
        lines.append(
            f"**Ranked by robustness** over {len(s.robustness[0].epsilons)} sample completions (every other one "
            "meshed further out, where the network is unsure), the palm off "
            f"by up to a few mm and degrees on each: most robust first (the {LIFT_TOP} best are lifted on every "
            f"sample, the {RECHECK_TOP} best of them twice and first, by the share of tests that lift the sample; "
            f"then the share of samples it holds on, then its {100 * ROBUST_QUANTILE:.0f}% ε), "
            "after those that lift the mesh."
            + (
                f" No grasp of the {s.method} mesh lifted {WIDEN_BELOW:.0%} of its sample tests, so the wider "
                f"search planned #{s.wider_from + 1}-#{len(s.grasps)} on the grasp envelope and ranked them with "
                "the others."
                if s.wider_from is not None
                else ""
            )
        )
    if real_capture:
        lines.append("**No ground truth**: this is a real capture; grasps cannot be executed on the true object.")
    done = [e for e in s.executions if e is not None]
    if len(done) > 1:
        lifted = [e.lift.success for e in done if e.lift is not None]
        lines.append(
            f"On the ground truth ({s.truth_name}), {len(done)} executed: mean joint error "
            f"{np.mean([e.joint_error for e in done]):.2f}°, pose error "
            f"{np.mean([e.pose_error for e in done]):.1f} mm"
            + (f", lifted {sum(lifted)}/{len(lifted)}" if lifted else "")
        )
    text = "  \n".join(lines)
    if selected is None or not s.grasps:
        return text
    k = selected
    g, e, hand = s.grasps[k], s.executions[k], get_hand(s.hand)
    x, y, z = 1000 * g.position
    a = g.approach
    text += (
        f"\n\n**Grasp #{k + 1}** · ε **{_epsilon_text(g.epsilon)}** · volume {g.volume:.4f} · "
        f"{len(g.contacts)} contacts · energy {1000 * g.energy:.1f} mm  \n"
        f"palm ({x:.0f}, {y:.0f}, {z:.0f}) mm · approach ({a[0]:.2f}, {a[1]:.2f}, {a[2]:.2f})"
        + (
            ""
            if g.lift is None
            else f"  \n**Lift check** on the {'envelope' if _wider(s, k) else s.method} mesh: {_lift_text(g.lift)}"
        )
        + (f"  \n{_robustness_line(s.robustness, _lifts(s), k)}" if s.robustness else "")
        + "\n\n"
    )
    header = "| joint | planned |" + (" executed |\n|---|---:|---:|" if e is not None else "\n|---|---:|")
    rows = [
        f"| {n} | {_joint_value(hand, n, g.joints[n])} |"
        + (f" {_joint_value(hand, n, e.joints[n])} |" if e is not None else "")
        for n in hand.joint_names
    ]
    text += header + "\n" + "\n".join(rows)
    if e is not None:
        text += (
            f"\n\n**On the ground truth** ({s.truth_name}): ε {_epsilon_text(e.epsilon)} · joint error "
            f"**{e.joint_error:.2f}°** · pose error **{e.pose_error:.1f} mm** · {_lift_text(e.lift)}"
            + ("" if e.start_clear else " · the backed-off start was in collision")
            + "  \n_Blue: the hand as executed; gold: the true object; the stick figure: the planned "
            "grasp. (The completion's mesh and CNN input layers were switched off to show the object.)_"
        )
    return text


def execution_summary(sid: int, name: str, results: list[ExecutionResult]) -> str:
    """A notification's body after executing ``results`` of segment ``sid`` on true object ``name``."""
    lifted = [r.lift.success for r in results if r.lift is not None]
    return (
        f"Segment {sid} on {name}: joint error {np.mean([r.joint_error for r in results]):.1f}°, "
        f"pose error {np.mean([r.pose_error for r in results]):.1f} mm"
        + (f", lifted {sum(lifted)}/{len(lifted)}" if lifted else "")
        + "."
    )
