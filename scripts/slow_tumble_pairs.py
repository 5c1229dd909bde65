"""diagnose on pairs of effects concealed in a slow, long tumble (README, "Measured"): 300 s at
10 Hz of a small body at ~0.3 rad/s (five multiple-shooting segments), no torque, the true
inertia as the sidecar's nominal, no gyro_sigma given; each record diagnosed once, whether both
effects are named, the explanation with its forms and gains, the worst axis's rms over the noise,
and what each true effect gains in that record (true_gains): the truth's model, started at the
true parameters and fitted, against the same without that effect; an effect that gains less
than its claim margin does not show in the record (a mode the torque-free tumble never excites),
and no search could name it. The last line counts the pairs both named, of all and of those
where both show.

Usage: PYTHONPATH=. python scripts/slow_tumble_pairs.py [--out OUT.json]
Cases: five pairs, seeds 0-2 (about 4 minutes on this 2-core machine: 218 s at 59b1ac6).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.fit import MODE_REACH, Data, Fit, Layout, Probe, claim_margin, fit_model
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.recordings import Recording
from inertia_gym.scenario import Scenario

PAIRS = (("internal_momentum", "gyro_bias"), ("internal_momentum", "constant_body_torque"),
         ("gyro_bias", "constant_body_torque"), ("constant_body_torque", "flexible_mode"),
         ("internal_momentum", "viscous_damping"))


def slow_tumble(effects, seed: int, omega_seed: int, duration: float = 300.0,
                noise: float = 5e-4) -> tuple[Recording, dict]:
    """`duration` s at 10 Hz of a small body tumbling at ~0.3 rad/s (initial rates drawn with
    omega_seed), no torque, gyro noise `noise` rad/s, with the effects (None, a name or a list,
    drawn with seed), the true inertia as the sidecar's nominal and no gyro_sigma in it; and the
    effects' true parameters by name."""
    rng = np.random.default_rng(omega_seed)
    inertia = ((0.1, 0.002, -0.001), (0.002, 0.12, 0.003), (-0.001, 0.003, 0.05))
    sc = Scenario(inertia_true=inertia, inertia_guess=inertia, omega0=tuple(rng.normal(0, 0.15, 3)),
                  gyro_sigma=noise, dt=0.1, tau_max=2e-4)
    rec, side = simulate_recording(sc, duration, effects, seed=seed, torque=False, sample_dt=0.1)
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects", "gyro_sigma")}
    truth = {e["name"]: e["params"] for e in side.get("effects") or [side["effect"]] if e}  # None: no effect
    return dataclasses.replace(rec, meta=meta), truth


def fitted_truth(truth: dict, d: Data, nominal: Fit) -> Fit:
    """The model of the true effects (name -> true parameters, simplest forms, in that order)
    fitted on d with the inertia and the segments' rates, started at the true parameters (and
    each segment's rates the nominal fit's or its first gyro sample's, whichever fit it better);
    each effect added to the fit of those before it, as the diagnosis adds them."""
    fit = nominal
    names = list(truth)
    for i in range(1, len(names) + 1):
        part, forms = names[:i], ("",) * i
        mode = truth.get("flexible_mode") if "flexible_mode" in part else None
        reach = MODE_REACH * float(mode["omega_n"]) if mode else fit.layout.omega_max
        layout = Layout.of(part, forms, d, reach)
        x0 = np.concatenate([nominal.x[:6], *(REGISTRY[n].pack(truth[n]) for n in part), nominal.x[6:]])
        x0 = Probe(layout, d, fit).with_segment_rates([x0])[0]
        fit = fit_model(part, forms, d, fit, start=x0, omega_max=reach)
    return fit


def true_gains(truth: dict, d: Data, nominal: Fit) -> dict:
    """Per true effect, the BIC the truth's fitted model gains over the same model without it
    (fitted_truth both): what the record shows of that effect beside the others."""
    whole = fitted_truth(truth, d, nominal)
    return {name: fitted_truth({n: p for n, p in truth.items() if n != name}, d, nominal).bic - whole.bic
            for name in truth}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="write the rows to this JSON file")
    args = ap.parse_args()
    rows = []
    for pair in PAIRS:
        for seed in range(3):
            rec, truth = slow_tumble(list(pair), seed, 300 + seed)
            t0 = time.perf_counter()
            report, arrays = diagnose(rec)
            wall = time.perf_counter() - t0
            named = [e["name"] for e in report["explanation"]]
            d = arrays["d"]
            gains = true_gains(truth, d, arrays["nominal"])
            rows.append({"pair": pair, "seed": seed, "both_named": set(pair) <= set(named),
                         "explanation": [(e["name"], e.get("form"), round(e["delta_bic"], 1))
                                         for e in report["explanation"]],
                         "true_gains": {n: round(g, 1) for n, g in gains.items()},
                         "both_show": all(g > claim_margin(d, n) for n, g in gains.items()),
                         "worst_axis_after": max(report["fit_after"]["rms_over_noise"]), "wall_s": wall})
            row = rows[-1]
            said = ", ".join(f"{n} {f or ''} {g}".replace("  ", " ") for n, f, g in row["explanation"])
            shown = ", ".join(f"{n} {g:.0f}" for n, g in row["true_gains"].items())
            print(f"{' + '.join(pair):45s} seed {seed}: {'both' if row['both_named'] else 'NOT both':8s} "
                  f"{said:70s} worst axis {row['worst_axis_after']:.2f}x  {wall:.1f} s; "
                  f"true gains {shown}", flush=True)
    show = [r for r in rows if r["both_show"]]
    print(f"both effects named on {sum(r['both_named'] for r in rows)} of {len(rows)}; "
          f"on {sum(r['both_named'] for r in show)} of the {len(show)} where both show in the record")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
