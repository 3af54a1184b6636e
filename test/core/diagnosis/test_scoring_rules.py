"""The diagnosis' rules on its scoring object: what closes the gap, what a candidate
costs (written once, on Scoring, instead of four and three times)."""

from __future__ import annotations

import math
from types import SimpleNamespace

from pmdc_ident.core.diagnosis.search import Fitted, Scoring
from pmdc_ident.core.diagnosis.verdict import Thresholds
from pmdc_ident.core.effects import BrushDrop, CoulombFriction
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import MotorParams

P = MotorParams(R=2.0, L=2e-3, Ke=0.05, Kt=0.05, J=2e-5, B=2e-6)


def _fitted(effects, gap, *, failed=False):  # type: ignore[no-untyped-def]
    fit = SimpleNamespace(model=Model(P, effects))
    return Fitted(tuple(e.NAME for e in effects), fit, None, gap, 0.0, failed)  # type: ignore[arg-type]


def test_closing_most_of_the_gap_or_down_to_the_noise():
    s = Scoring(10.0, 0.3, Thresholds())
    assert s.closes_most(5.0) and not s.closes_most(5.01)
    assert s.closes(5.0) and s.closes(1.0) and not s.closes(5.01)  # 1.0: the noise
    small = Scoring(1.5, 0.3, Thresholds())
    assert not small.closes_most(0.9) and small.closes(0.9)


def test_a_candidate_costs_its_gap_and_the_penalty_of_what_it_fits():
    s = Scoring(10.0, 0.3, Thresholds())
    assert s.penalized(_fitted((CoulombFriction(0.01),), 2.0)) == 2.0 + 0.3
    # a hard brush drop (knee at its limit) fits one field, a contact film's two
    assert s.penalized(_fitted((BrushDrop(1.0),), 2.0)) == 2.0 + 0.3
    assert s.penalized(_fitted((BrushDrop(1.0, 0.5),), 2.0)) == 2.0 + 2 * 0.3
    assert s.penalized(_fitted((CoulombFriction(0.01),), 2.0, failed=True)) == math.inf
