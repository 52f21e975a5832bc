"""What the Grasps folder says: the grasp dropdown's entries and the text about the listed
segment's plan, the selected grasp and its execution. Plain values in, markdown out; no viser.

Units shown: millimetres for positions and prismatic joints, degrees for revolute joints; a joint
error in the unit of the hand's finger joints (:func:`joint_error_unit`: degrees for the Barrett's
revolute fingers, millimetres for the Panda's prismatic ones); epsilon (the grasp quality) as the
planner computes it; wall-clock seconds per stage (:func:`stage_times`), the same figures in the
notices and the panel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ...grasp.execute import ExecutionResult
from ...grasp.hands import HAND_NAMES, Hand, get_hand
from ...grasp.robust import LIFT_TOP, RECHECK_TOP, ROBUST_QUANTILE, WIDEN_BELOW, Robustness, rank_robust
from ...grasp.state import LiftResult
from .state import MAX_GRASPS, SegmentGrasps

NO_PLAN = "_Select a segment, then plan grasps on it._"
# The stages a segment's grasps go through, as keys of ``SegmentGrasps.seconds`` (those of
# ``Pick.seconds`` in :mod:`shapeviewer.grasp.pick`), with what the texts call them.
STAGE_LABELS = {"plan": "planning", "rank": "ranking", "wider": "wider search"}


def stage_times(seconds: Mapping[str, float]) -> str:
    """``planning 19.8 s · ranking 12.1 s · wider search 8.0 s``: the wall-clock seconds of the
    stages in ``seconds`` (keys of :data:`STAGE_LABELS`), in that order."""
    return " · ".join(f"{label} {seconds[key]:.1f} s" for key, label in STAGE_LABELS.items() if key in seconds)


def _finger_joint_kinds(hand: Hand) -> set[str]:
    """The URDF joint types (``revolute``, ``prismatic``, ...) of the joints a hand's closing dofs move."""
    by_name = {j.name: j for j in hand.model.joints}
    return {by_name[n].kind for n, moved in zip(hand.joint_names, hand.closing_joints) if moved}


def joint_error_unit(hand_name: str) -> str:
    """The unit of an execution's joint error for hand ``hand_name``
    (:func:`~shapeviewer.grasp.execute.joint_error` averages the finger joints in degrees when they
    are revolute, in millimetres when prismatic): ``"°"`` or ``" mm"`` (with its space), ``" (° and
    mm)"`` for a hand with both."""
    kinds = _finger_joint_kinds(get_hand(hand_name))
    if kinds <= {"revolute", "continuous"}:
        return "°"
    return " mm" if kinds == {"prismatic"} else " (° and mm)"


def joint_error_text(hand_name: str, value: float, digits: int = 2) -> str:
    """A joint error of hand ``hand_name`` with its unit: ``2.90°`` (Barrett), ``1.25 mm`` (Panda)."""
    return f"{value:.{digits}f}{joint_error_unit(hand_name)}"


def hand_opening(hand: Hand) -> float | None:
    """How wide a parallel gripper opens (metres: the travel of its prismatic fingers, the Panda's
    80 mm); None for a hand whose fingers are revolute (the Barrett wraps an object, no one width)."""
    if _finger_joint_kinds(hand) != {"prismatic"}:
        return None
    return float(sum(abs(o - c) for o, c in zip(hand.dof_open, hand.dof_closed)))


def plan_advice(s: SegmentGrasps) -> str | None:
    """What the plan ``s`` cannot do and what to try, or None when it has a grasp that lifts and the
    object fits the hand: the object is wider at its narrowest (``s.width``) than the hand opens
    (:func:`hand_opening`), or no grasp lifts the mesh in simulation (nor, once ranked by
    robustness, its sample completions)."""
    opening = hand_opening(get_hand(s.hand))
    too_wide = opening is not None and s.width is not None and s.width > opening
    lifts = any(g.lifted for g in s.grasps) or any(r.lifted for r in s.robustness or [])
    if not too_wide and (lifts or not s.grasps):
        return None
    other = " or ".join(f"the {h}" for h in HAND_NAMES if h != s.hand)
    said = []
    if too_wide:
        assert s.width is not None and opening is not None  # too_wide
        said.append(
            f"The object is {100 * s.width:.1f} cm across at its narrowest, wider than the {s.hand} opens "
            f"({100 * opening:.0f} cm): its fingers cannot close around it."
        )
    if s.grasps and not lifts:
        n = len(s.grasps)
        said.append(
            ("The grasp does not" if n == 1 else f"None of the {n} grasps")
            + f" lift{'s' if n > 1 else ''} the {s.method} mesh in simulation"
            + (" or its sample completions" if s.robustness else "")
            + "."
        )
    tries = [f"{other} hand"]
    if not too_wide:
        if len(s.grasps) < MAX_GRASPS:
            tries.append(f"more grasps (up to {MAX_GRASPS})")
        if s.robustness is None:
            tries.append("Rank by robustness (it plans on the grasp envelope too when no grasp holds up)")
    said.append("Try " + (tries[0] if len(tries) == 1 else ", ".join(tries[:-1]) + " or " + tries[-1]) + ".")
    return " ".join(said)


def _count(n: int, noun: str) -> str:
    """``"1 sample completion"``, ``"8 sample completions"``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


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
    n = len(s.grasps)
    lines = [
        f"**Segment {s.segment_id}** · {s.hand} on the {s.method} mesh · **{n}** {'grasp' if n == 1 else 'grasps'} "
        f"({n_fc} force closure"
        + (f", {sum(checked)} of {len(checked)} checked lift the mesh in simulation: first" if checked else "")
        + f") · {stage_times(s.seconds)}"
    ]
    advice = plan_advice(s)
    if advice is not None:
        lines.append(f"**⚠ {advice}**")
    if s.grasps:
        best = max(g.epsilon for g in s.grasps)
        lines.append(f"Colour: ε from red (0) to green (ε = {best:.3f}, the best); grey: no force closure.")
    if s.robustness:
        lines.append(
            f"**Ranked by robustness** over {_count(len(s.robustness[0].epsilons), 'sample completion')} "
            "(every other one meshed further out, where the network is unsure), the palm off "
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
            f"{joint_error_text(s.hand, float(np.mean([e.joint_error for e in done])))}, pose error "
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
            f"**{joint_error_text(s.hand, e.joint_error)}** · pose error **{e.pose_error:.1f} mm** · "
            f"{_lift_text(e.lift)}"
            + ("" if e.start_clear else " · the backed-off start was in collision")
            + "  \n_Blue: the hand as executed; gold: the true object; the stick figure: the planned "
            "grasp. (The completion's mesh and CNN input layers were switched off to show the object.)_"
        )
    return text


def execution_summary(sid: int, name: str, hand: str, results: list[ExecutionResult]) -> str:
    """A notification's body after executing ``results`` (grasps of hand ``hand``) of segment ``sid``
    on true object ``name``."""
    lifted = [r.lift.success for r in results if r.lift is not None]
    return (
        f"Segment {sid} on {name}: joint error "
        f"{joint_error_text(hand, float(np.mean([r.joint_error for r in results])), digits=1)}, "
        f"pose error {np.mean([r.pose_error for r in results]):.1f} mm"
        + (f", lifted {sum(lifted)}/{len(lifted)}" if lifted else "")
        + "."
    )
