"""The decision trace of the search: what each word's test found and what was decided, as data.

:func:`models.diagnose.detectors.select_effects` appends one :class:`Decision`
per word and round; :func:`explain` turns a decision into the sentence D.json
(``model.rejected``) and the report show.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

#: Outcomes of a decision.
NAMED, ALTERNATIVE, BELOW_MARGIN, NOT_PHYSICAL, UNSUPPORTED, UNCONFIRMED, MASKED, DROPPED = (
    "named", "alternative", "below margin", "not physical", "unsupported", "unconfirmed", "masked", "dropped")


@dataclass(frozen=True)
class Decision:
    """One word's test in one round of the search, and what was decided.

    Attributes
    ----------
    word : str
        Effect word.
    round : int
        Round of the greedy search (0 = the first effect).
    gain : float
        Relative fall of the pooled held-out squared error.
    need : float
        The margin it had to beat.
    wins, changed, folds : int
        Folds where the held-out error fell, folds it changed, folds in all.
    min_wins : int
        The fold majority asked for.
    law : str
        ``"exact"`` (the nonlinear law, refined) or ``"linearized"`` (the first-order columns).
    outcome : str
        One of :data:`NAMED`, :data:`ALTERNATIVE`, :data:`BELOW_MARGIN`, :data:`NOT_PHYSICAL`,
        :data:`UNSUPPORTED`, :data:`UNCONFIRMED`, :data:`MASKED`, :data:`DROPPED` (named, then no
        longer earning its place once the words named after it are in: the backward check).
    why : str
        The detail of a refusal (parameters out of range, missing rows, holdout figures), or "".
    """

    word: str
    round: int
    gain: float
    need: float
    wins: int
    changed: int
    folds: int
    min_wins: int
    law: str
    outcome: str
    why: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def explain(d: Decision) -> str:
    """One sentence for a decision."""
    test = (f"held-out error {-100 * d.gain:+.2f} % with the {d.law} law (needs below -{100 * d.need:.2f} %), "
            f"lower in {d.wins}/{d.folds} folds, {d.changed} changed")
    if d.outcome == BELOW_MARGIN:
        return f"{test} (needs {d.min_wins}, or a majority of two or more changed)"
    if d.outcome == NOT_PHYSICAL:
        return f"fits better but is not physical or not resolved: {d.why}"
    if d.outcome == UNSUPPORTED:
        return f"fits better but the recording does not show its law: {d.why}"
    if d.outcome == MASKED:
        return f"fits, but not asserted: {d.why}"
    if d.outcome == DROPPED:
        return f"named, then dropped by the backward check on the final chain: {d.why}; not asserted"
    if d.outcome == UNCONFIRMED:
        return f"passed the cross-validation but not the holdout: {d.why}; not asserted"
    return f"{test}: {d.why}" if d.why else test
