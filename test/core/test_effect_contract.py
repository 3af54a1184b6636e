"""Every registered effect provides every hook of its contract (core/effects/base.py).

The model, the fits, the diagnosis, the benchmark's truth and the exports loop over
``EFFECT_TYPES``; an effect that forgets a hook would be skipped silently there. These
checks fail instead, for any effect added to the registry.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pmdc_ident.benchmark.truth import EQUATIONS, GENERATORS, LADDERS, VOCABULARY
from pmdc_ident.core.design.reveal import RECIPES
from pmdc_ident.core.diagnosis.verdict import EFFECT_PRIOR, separating_test
from pmdc_ident.core.effects import (
    DEFAULT_CANDIDATES,
    EFFECT_NAMES,
    EFFECT_TYPES,
    CandidateContext,
    DataScales,
    Effect,
    MujocoContext,
    RecordScales,
    SimPath,
    layout,
)
from pmdc_ident.core.model import Model, effect_coefficients, simulate
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.params import MotorParams
from pmdc_ident.exports.mujoco_xml import mujoco_xml

NAMES = list(EFFECT_NAMES)
SCALES = (
    DataScales(0.05, 12.0, 300.0, 2.0, 1e-3, 40.0, 30.0, (1, 14)),
    DataScales(1e-9, 1e-6, 1e-6, 1e-6, 0.02, 1e-9, 1e-6, (1,)),  # odd units
    DataScales(300.0, 900.0, 5e4, 800.0, 1e-4, 1e6, 600.0, (3,)),
)
MOTOR = MotorParams(R=2.0, L=2e-3, Ke=0.05, Kt=0.05, J=2e-5, B=2e-6)


def typical(cls: type[Effect]) -> Effect:
    """The effect at the start the diagnosis would scan first on a typical record."""
    return cls.starts(SCALES[0])[-1]


@pytest.mark.parametrize("name", NAMES)
def test_identity_and_fields_match_the_specs(name: str) -> None:
    cls = EFFECT_TYPES[name]
    assert cls.NAME == name and cls.DESCRIPTION
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen  # type: ignore[attr-defined]
    assert [f.name for f in dataclasses.fields(cls)] == list(cls.SPECS)
    for spec in cls.SPECS.values():
        assert spec.unit and spec.description and spec.lower <= spec.upper
        assert spec.limit is None or spec.lower <= spec.limit <= spec.upper


@pytest.mark.parametrize("name", NAMES)
def test_kernel_slots_are_its_own_fields_in_free_slots(name: str) -> None:
    cls = EFFECT_TYPES[name]
    assert set(cls.KERNEL_SLOTS) <= set(cls.SPECS)
    motor_slots = {layout.R, layout.L, layout.KE, layout.KT, layout.J, layout.B}
    for slot in (*cls.KERNEL_SLOTS.values(), *cls.KERNEL_NEUTRAL):
        assert slot not in motor_slots and 0 <= slot < layout.N_COEF
    others = [c for n, c in EFFECT_TYPES.items() if n != name]
    taken = {s for c in others for s in c.KERNEL_SLOTS.values()}
    assert not taken & set(cls.KERNEL_SLOTS.values()), "two effects share a slot"


@pytest.mark.parametrize("name", NAMES)
def test_its_numbers_reach_the_kernel_and_change_the_simulation(name: str) -> None:
    # the coefficient writer and the kernel lines: with the effect the motor behaves
    # differently from without it, on a record that drives it both ways, coasts and
    # turns several times (every effect of the vocabulary shows on it)
    cls = EFFECT_TYPES[name]
    e = typical(cls)
    base, with_e = Model(MOTOR), Model(MOTOR, (e,))
    c0, c1 = effect_coefficients(base), effect_coefficients(with_e)
    assert c0.size == c1.size == layout.N_COEF
    assert not np.array_equal(c0, c1), "write_coefficients wrote nothing"
    rate = 1000.0
    v = np.concatenate(
        [np.full(300, 6.0), np.full(300, -12.0), np.full(200, np.nan), np.zeros(200)]
    )
    v += np.where(np.isnan(v), 0.0, 2.0 * np.sin(np.arange(v.size) / 7.0))
    a = simulate(base, v, 1 / rate)
    b = simulate(with_e, v, 1 / rate)
    diff = max(
        float(np.max(np.abs(a.current - b.current))), float(np.max(np.abs(a.speed - b.speed)))
    )
    assert diff > 1e-6, "the kernel does not read this effect"


@pytest.mark.parametrize("name", NAMES)
def test_simulation_flags_are_consistent(name: str) -> None:
    cls = EFFECT_TYPES[name]
    assert isinstance(cls.SIM_PATH, SimPath)
    e = typical(cls)
    if cls.SIM_PATH is SimPath.FAST:
        # the fast kernel differentiates every fitted field
        assert set(cls.FAST_COLUMNS) == set(cls.fitted_names())
        cols = set(cls.FAST_COLUMNS.values()) - {layout.COL_MEASURED_CURRENT}
        assert all(layout.COL_TC <= c < layout.N_SENS for c in cols)
    else:
        assert not cls.FAST_COLUMNS
    # re-discretised: always (its fit is the slowest); a brush drop only in its second form
    if cls.SIM_PATH is SimPath.REDISCRETISED:
        assert e.varies_within_sample()
    if e.varies_within_sample():
        assert cls.SIM_PATH is not SimPath.FAST
    if cls.LINEAR_BETWEEN_SAMPLES:
        assert not e.varies_within_sample()


@pytest.mark.parametrize("name", NAMES)
def test_starts_are_valid_effects_of_its_kind_for_any_scales(name: str) -> None:
    cls = EFFECT_TYPES[name]
    for sc in SCALES:
        starts = cls.starts(sc)
        assert starts and all(type(s) is cls for s in starts)
    assert all(f > 0 for f in cls.L_SCAN)
    assert cls.untestable(CandidateContext((1,), False)) == ""
    assert isinstance(cls.untestable(CandidateContext((), True)), str)


@pytest.mark.parametrize("name", NAMES)
def test_forms_and_settings_name_fields_that_can_carry_them(name: str) -> None:
    cls = EFFECT_TYPES[name]
    if cls.SECOND_FORM is not None:
        spec = cls.SPECS[cls.SECOND_FORM]
        assert spec.fitted and spec.limit is not None
        # the scan has starts in the limit and out of it
        starts = cls.starts(SCALES[0])
        limits = [getattr(s, cls.SECOND_FORM) == spec.limit for s in starts]
        assert any(limits) and not all(limits)
    else:
        # a field with a limit is either the second form or a further one
        limited = [n for n, s in cls.SPECS.items() if s.limit is not None]
        assert limited == ([cls.FURTHER_FORM[0]] if cls.FURTHER_FORM else [])
    if cls.FURTHER_FORM is not None:
        field, start = cls.FURTHER_FORM
        spec = cls.SPECS[field]
        assert spec.fitted and spec.limit is not None and start != spec.limit
        assert spec.lower <= start <= spec.upper
    if cls.SETTING_SCAN is not None:
        field, values = cls.SETTING_SCAN
        assert not cls.SPECS[field].fitted and len(values) >= 2
        assert {getattr(s, field) for s in cls.starts(SCALES[0])} == set(values)


@pytest.mark.parametrize("name", NAMES)
def test_separating_tests_name_registered_neighbours_once(name: str) -> None:
    cls = EFFECT_TYPES[name]
    assert cls.SEPARATING_TESTS, "an effect can be confused with something"
    for other, text in cls.SEPARATING_TESTS.items():
        assert other in EFFECT_TYPES and other != name and text
        # a pair is declared by one of the two only
        assert name not in EFFECT_TYPES[other].SEPARATING_TESTS
        assert separating_test(name, other) == separating_test(other, name) == text


def test_prior_ranks_are_unique_and_order_every_effect() -> None:
    priors = [cls.PRIOR for cls in EFFECT_TYPES.values()]
    assert len(set(priors)) == len(priors)
    assert sorted(EFFECT_PRIOR) == sorted(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_benchmark_truth_has_what_the_ladder_asks(name: str) -> None:
    cls = EFFECT_TYPES[name]
    if cls.DEFAULT_CANDIDATE:
        # the diagnosis tries it by default: the benchmark must score it
        assert cls.BENCHMARK_LADDER is not None
    if cls.BENCHMARK_LADDER is None:
        assert name not in VOCABULARY
        return
    assert name in VOCABULARY and name in GENERATORS
    assert len(EQUATIONS[name]) >= 2  # never only the candidate's own equation
    unit, sizes = LADDERS[name]
    assert unit and len(sizes) == 4 and list(sizes) == sorted(sizes)


@pytest.mark.parametrize("name", NAMES)
def test_the_mujoco_export_carries_it_or_says_why_not(name: str) -> None:
    cls = EFFECT_TYPES[name]
    e = typical(cls)
    terms = e.mujoco_terms(MujocoContext(reduction=2.0, resistance_ohm=2.0, current_scale=1.0))
    # carried (terms and the mapping in words) or not (and why): never both, never neither
    assert terms.carries_anything() == bool(cls.MUJOCO_MAPPING) != bool(cls.MUJOCO_NOT_CARRIED)
    spec = MotorSpec("probe", Model(MOTOR, (e,)))
    out = mujoco_xml(spec, flavour="dcmotor")
    if cls.MUJOCO_NOT_CARRIED:
        assert f"{name}: {cls.MUJOCO_NOT_CARRIED}" in out.not_carried
        assert not any(line.startswith(f"{name}:") for line in out.carried)
    else:
        assert f"{name}: {cls.MUJOCO_MAPPING}" in out.carried
        assert all(
            line == f"{name}: {terms.partial}"
            for line in out.not_carried
            if line.startswith(f"{name}:")
        )


@pytest.mark.parametrize("name", NAMES)
def test_a_reveal_plan_has_a_recipe_for_it(name: str) -> None:
    assert EFFECT_TYPES[name].REVEAL in RECIPES


RECORDS = (
    RecordScales(0.2, 12.0, 4.0, 300.0, 40.0, 1e-3, (4.0, 16.0)),
    RecordScales(2e-4, 3.0, 0.05, 2000.0, 0.01, 0.02, ()),  # coreless, no turn resolved
    RecordScales(300.0, 900.0, 800.0, 5e3, 1e6, 1e-4, (48.0,)),
)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("sc", RECORDS)
def test_detection_probes_are_its_own_effect_sized_from_the_record(
    name: str, sc: RecordScales
) -> None:
    # the detection limit sizes every effect through these hooks; a probe that cannot
    # build its effect at its first size would be reported "not shown" for any record
    cls = EFFECT_TYPES[name]
    probes = cls.detection_probes(sc)
    assert probes or cls.DETECTION_NOT_SHOWN, "no probe and no reason"
    for p in probes:
        assert isinstance(p.make(p.first), cls)
        assert p.first > 0 and p.scale > 0 and p.n_params >= 1
        assert p.unit and p.relative_to
    assert 0.0 <= cls.detection_floor(sc) < float("inf")
    assert len(probes) <= 1 or cls.detection_detail(sc), "a limit over several probes says so"


def test_default_candidates_are_registered_in_order() -> None:
    assert list(DEFAULT_CANDIDATES) == [n for n in NAMES if EFFECT_TYPES[n].DEFAULT_CANDIDATE]
