"""Where the simulation kernels read each number: one named constant per slot.

:func:`pmdc_ident.core.model.effect_coefficients` fills a vector of :data:`N_COEF`
numbers from a model (each effect writes its own slots,
:meth:`~pmdc_ident.core.effects.base.Effect.write_coefficients`); the numba kernels of
:mod:`pmdc_ident.core.model` and :mod:`pmdc_ident.core.estimators.output_error.kernel`
read them by these names. The fast output-error kernel also propagates sensitivities
in columns named here (``COL_*``): an effect on that path says which column carries
each of its fields (``FAST_COLUMNS``).

numba freezes these constants into the compiled kernels, so this module is one of the
kernel sources whose hash names the on-disk cache (``core._jit.KERNEL_SOURCES``): a
changed slot can never run with a kernel compiled for the old one.

A new effect that the kernel must read takes the next free slot and raises
:data:`N_COEF`; the contract test (``test/core/test_effect_contract.py``) checks that no
two effects share a slot.
"""

from __future__ import annotations

# the motor (R..B)
R, L, KE, KT, J, B = 0, 1, 2, 3, 4, 5
# coulomb_friction
TC = 6
# stribeck_friction: extra breakaway torque, Stribeck speed, shape exponent
TS, WS, DS = 7, 8, 18
# quadratic_drag
CQ = 9
# load_torque
TL = 10
# brush_drop: the drop and its knee current (0: the hard sign)
VB, IB = 11, 19
# cogging: amplitude, periods per turn, phase
TCOG, NCOG, PHCOG = 12, 13, 14
# resistance_drift: k of R (1 + k q), the winding's time constant (0: no cooling), and
# the flux loss kf of Ke (1 - kf q)
KR, TAUQ, KF = 15, 17, 20
# inductance_saturation
ISAT = 16
# current_offset (added to the measured current)
I_OFF = 21
# dead_zone (on the command)
V_DZ = 22
# delay: transport delay and first-order lag (on the command)
DELAY, LAG = 23, 24
# torque_dependent_friction: the share of the motor's torque lost against the motion
MU = 25
N_COEF = 26

# Sensitivity columns of the fast output-error kernel: R..B per log of the value,
# then the torques it differentiates and the initial states.
COL_R, COL_L, COL_KE, COL_KT, COL_J, COL_B = 0, 1, 2, 3, 4, 5
COL_TC, COL_TL, COL_I0, COL_W0, COL_TH0 = 6, 7, 8, 9, 10
COL_TS, COL_WS, COL_CQ = 11, 12, 13
N_SENS = 14
# not a kernel column: the field adds to the measured current (its sensitivity is 1 on
# every current row)
COL_MEASURED_CURRENT = -1
