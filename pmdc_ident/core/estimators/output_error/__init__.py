"""Output-error identification: simulation residuals over all segments at once.

Seed 001's method done properly. The model is simulated free-running on every
segment from its own (estimated) initial state and, for a segment cut from a
longer record, its history (``Segment.history_voltage`` fills a delay line,
``Segment.history_heat_a2s`` starts a resistance drift), and the residuals on current
and speed (or position, when speed is absent) are scaled per signal by the
noise level, so the cost is the negative log-likelihood of white Gaussian
measurement noise. Parameters:

* the motor parameters ``R, L, Ke, Kt, J, B`` (positive, fitted in log space);
* effect parameters ``"<effect>.<field>"`` of the effects present in the model
  (only fields whose :class:`~pmdc_ident.core.effects.ParamSpec` is ``fitted``);
* per segment, the initial current, speed and (when position is fitted) angle.

Two simulators share one Levenberg-Marquardt solver:

* the **fast path** (the linear model plus the effects whose ``SIM_PATH`` is
  ``FAST``: ``coulomb_friction``, ``stribeck_friction``, ``quadratic_drag``,
  ``load_torque``, ``current_offset``): one exact zero-order-hold step per sample, with the
  sensitivity equations propagated alongside the state in a numba kernel (the
  sensitivity equations are themselves linear ZOH systems; their matrices come
  from Van Loan block exponentials), so the Jacobian is analytic;
* the **general path** (any other effect): :func:`pmdc_ident.core.model.simulate`
  with sub-steps and a forward-difference Jacobian.

Scale ambiguity (docs/design.md §2): from voltage, current and speed only, ``(Kt, J,
B)`` are known up to a common factor. ``closure="Kt=Ke"`` (the default) ties
``Kt`` to ``Ke``; fixing ``Kt`` or ``J`` replaces the closure. Without voltage
(a current-controlled drive) only the mechanical side is fitted, given ``Kt``.

Modules, in the order the data flow through them: :mod:`.segments` (segments
prepared for the fit, noise levels), :mod:`.parameters` (names, bounds, scaling),
:mod:`.kernel` and :mod:`.simulators` (the two simulators), :mod:`.problem`
(residuals and normal equations), the package's one Levenberg-Marquardt solver
(:mod:`pmdc_ident.core.estimators.solver`), :mod:`.results` (:class:`FitResult`) and
:mod:`.fit` (:func:`fit_output_error`).
"""

from __future__ import annotations

from pmdc_ident.core.estimators.output_error.fit import CLOSURE_KT_KE, fit_output_error
from pmdc_ident.core.estimators.output_error.results import FitResult, Prediction

__all__ = ["CLOSURE_KT_KE", "FitResult", "Prediction", "fit_output_error"]
