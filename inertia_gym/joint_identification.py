"""One body, several recordings: one inertia fitted to them all.

``identify_joint(recordings)``: each recording is identified on its own (identification.identify)
and, together, by the same two estimates over all of them:

* the equation error pooled over every recording's windows (each record's noise and model
  error in the covariance: equation_error.pooled);
* the output error with one inertia and each recording's own initial state and noise level
  (multiple shooting, a segment per recording: output_error.solve_shooting), from the mean of
  the single fits.

The joint output error is reported where it passes the lack-of-fit test and its covariance
expects the smaller error (uncertainty.choose); else the pooled equation error. The
recordings' own estimates are tested against each other: the chi-square of their deviations
from their precision-weighted mean, on 6 (R - 1) degrees of freedom (5 (R - 1) at a fixed
trace); a small p-value says they are not one body's, or their intervals are too narrow.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy import stats

from inertia_gym.errors import ConfigError, EstimatorDivergedError, RecordingError
from inertia_gym.estimation import output_error
from inertia_gym.estimation.equation_error import pooled, system_of
from inertia_gym.estimation.inertia_param import nearest_realizable, phi_from_inertia
from inertia_gym.estimation.uncertainty import (
    TEST_LEVEL,
    InertiaEstimate,
    choose,
    homogeneity,
    inertia_estimate,
)
from inertia_gym.identification import Identification, identify_prepared
from inertia_gym.prepare import Prepared, prepared
from inertia_gym.recordings import Recording


@dataclasses.dataclass(frozen=True)
class JointIdentification:
    """identify_joint()'s result.

    names; estimate (InertiaEstimate, the reported joint one); estimator ('output error' or
    'equation error'); reference (the pooled equation error); singles (each recording's
    Identification); agreement_chi2, agreement_dof, agreement_p (the singles against their
    weighted mean); rms_over_noise (the joint output-error fit's); wall_s; notes.
    """

    names: tuple[str, ...]
    estimate: InertiaEstimate
    estimator: str
    reference: InertiaEstimate
    singles: tuple[Identification, ...]
    agreement_chi2: float
    agreement_dof: int
    agreement_p: float
    rms_over_noise: float
    wall_s: float
    notes: tuple[str, ...]

    def summary(self) -> dict:
        """joint.json's keys (all finite numbers)."""
        return {"names": list(self.names), **self.estimate.summary(), "estimator": self.estimator,
                "equation_error": self.reference.summary(),
                "per_recording": [{"name": s.name, "estimator": s.estimator,
                                   "principal_moments": s.estimate.principal().moments.tolist(),
                                   "theta": s.estimate.theta.tolist(), "ci95": s.estimate.ci95().tolist()}
                                  for s in self.singles],
                "agreement_chi2": float(self.agreement_chi2), "agreement_dof": int(self.agreement_dof),
                "agreement_p": float(self.agreement_p), "rms_over_noise": float(self.rms_over_noise),
                "notes": list(self.notes), "wall_s": float(self.wall_s)}


def _joint_output_error(preps, singles, trace_ref) -> tuple[InertiaEstimate, float, bool]:
    """(estimate, rms over the noise, passes the lack-of-fit test) of one inertia over every
    record, each from its own initial state (a segment per record), at its own noise level.
    """
    probs = [output_error.problem_from(p, p.sigma) for p in preps]
    offset, grids, meas, t_end = 0, [], [], 0.0
    for pr in probs:
        t = pr.t_grid - pr.t_grid[0] + t_end
        grids.append((t, pr.tau_grid, pr.h_grid, pr.n_sub))
        meas.append(pr.meas_idx + offset)
        offset += t.size
        t_end = t[-1] + 1.0
    seg = np.r_[0, np.cumsum([pr.meas_idx.size for pr in probs])]
    first = probs[0]
    joint = dataclasses.replace(
        first, t_grid=np.concatenate([g[0] for g in grids]), tau_grid=np.concatenate([g[1] for g in grids]),
        h_grid=np.concatenate([g[2] for g in grids]), n_sub=np.concatenate([g[3] for g in grids]),
        meas_idx=np.concatenate(meas), z_w=np.concatenate([pr.z_w for pr in probs]),
        z_q=None if first.z_q is None else np.concatenate([pr.z_q for pr in probs]),
        sigma_w=np.concatenate([np.broadcast_to(pr.sigma_w, pr.z_w.shape) for pr in probs]),
        fit_bias=False, fix_scale=all(pr.fix_scale for pr in probs))
    mean = np.mean([s.estimate.inertia for s in singles], axis=0)
    if joint.fix_scale:
        mean = mean * trace_ref / np.trace(mean)
    lo = output_error.local_indices(joint)
    states = [np.r_[pr.z_w[0], np.zeros(lo.size - 3)] for pr in probs]
    x = np.r_[phi_from_inertia(nearest_realizable(mean)), np.concatenate(states)]
    q_refs = np.array([pr.z_q[0] if pr.z_q is not None else [1.0, 0, 0, 0] for pr in probs])
    stage = output_error.solve_shooting(output_error.Shooting(joint, seg), x, q_refs, None,
                                        output_error.FINAL_ITER)
    cov = np.zeros((6, 6)) if stage.global_cov is None else stage.global_cov[:6, :6]
    rms = stage.rms
    est = inertia_estimate(stage.x[:6], cov * max(1.0, rms ** 2), joint.fix_scale, trace_ref)
    dof = max(stage.evaluation.r.size - stage.x.size, 1)
    passes = stats.chi2.sf(float(stage.evaluation.r @ stage.evaluation.r), dof) >= 1.0 - TEST_LEVEL
    return est, rms, passes


def identify_joint(recordings: list[Recording], singles: list[Identification] | None = None,
                   preps: list[Prepared] | None = None) -> JointIdentification:
    """One inertia from several recordings of one body (see the module docstring). singles: the
    recordings' own identify() results, and preps their prepared records (prepare.prepared),
    where already at hand (computed where None).
    """
    if len(recordings) < 2:
        raise RecordingError("a joint identification needs at least two recordings of the body")
    started = time.perf_counter()
    preps = [prepared(rec) for rec in recordings] if preps is None else list(preps)
    singles = [identify_prepared(p) for p in preps] if singles is None else list(singles)
    seen = [p.rec.sees_scale for p in preps]
    if any(seen) != all(seen):
        raise RecordingError("some recordings fix the inertia's scale (a known torque or momentum) and "
                             "others do not: identify them apart, or leave out those that do not")
    nominals = [p.rec.inertia_nominal for p in preps if p.rec.inertia_nominal is not None]
    trace_ref = float(np.trace(nominals[0])) if nominals else 1.0
    systems = [system_of(p.rec.t - p.rec.t[0], p.rec.w, p.rec.tau, p.rec.h, trace_ref, p.usable, p.level)
               for p in preps]
    ee = pooled(systems, trace_ref)
    reference = InertiaEstimate(ee.theta, ee.theta_cov, ee.scale_seen)
    notes = []
    try:
        oe, rms, passes = _joint_output_error(preps, singles, trace_ref)
    except (EstimatorDivergedError, ConfigError, np.linalg.LinAlgError) as err:
        oe, rms, passes = None, float("nan"), False
        notes.append(f"the joint output-error fit failed ({err}): the equation error is reported")
    choice = choose(oe, reference, True) if oe is not None and passes else None
    if choice is not None and choice.efficient:
        est, estimator = oe, "output error"
    else:
        est, estimator = reference, "equation error"
        if oe is not None and not passes:
            notes.append("the joint output-error fit fails the lack-of-fit test: the rigid model leaves "
                         "physics out, and the pooled equation error is reported")
        elif choice is not None:
            notes.append(f"the pooled equation error is reported: its intervals expect a relative error "
                         f"of {100 * choice.expected[1]:.2g} %, the joint output error's "
                         f"{100 * choice.expected[0]:.2g} %")
    chi2, dof, p = dataclasses.astuple(homogeneity([s.estimate.theta for s in singles],
                                                   [s.estimate.theta_cov for s in singles]))
    if p < 1.0 - TEST_LEVEL:
        notes.append(f"the recordings' own estimates disagree beyond their intervals (chi-square {chi2:.3g} "
                     f"on {dof} degrees of freedom): not one body's, or their intervals are too narrow")
    return JointIdentification(tuple(r.name for r in recordings), est, estimator, reference, tuple(singles),
                               chi2, dof, p, rms, time.perf_counter() - started, tuple(notes))


__all__ = ["JointIdentification", "identify_joint"]
