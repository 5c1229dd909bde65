"""The markdown summary of one diagnosis for people (summary.md), worded from the report.json
dict alone: the verdict, the explanation and its fitted physics with intervals and units, the
inertia's shape, the record and its noise, every effect tried, the invariants and what to do next.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.analysis import BEYOND_CATALOGUE, NOISE_READ_HIGH, NOT_READ
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.effects.base import matrix6
from inertia_gym.discrepancy.effects.flexible_mode import pole_spread
from inertia_gym.discrepancy.fit import LATTICE_REPLAYS
from inertia_gym.discrepancy.selection import TIE_BIC
from inertia_gym.estimation.uncertainty import SCALE_SIGMA_IDENTIFIED
from inertia_gym.prepare import CLIP_ADVICE
from inertia_gym.recordings import retimed_note, window_note

#: A principal-moment ratio whose 95 % interval is wider than this says little of the body's shape.
RATIO_SPREAD = 0.1


def _fmt(values) -> str:
    return "no valid fit" if values is None else str(np.round(values, 2).tolist())


def _significant(values, digits: int = 4):
    """Nested lists of floats: values (any shape) rounded to `digits` significant digits, so that
    a 5e-4 kg·m² body's parameters and a 2e-5 rad/s noise level stay readable (fixed decimals
    printed them as 0.0).
    """
    rounded = np.vectorize(lambda v: float(f"{v:.{digits}g}"), otypes=[float])
    return rounded(np.asarray(values, float)).tolist()


#: Parameters with more numbers than this are told by their count and range (a momentum
#: profile's knots), not number by number.
LISTED_NUMBERS = 6


@dataclasses.dataclass(frozen=True)
class _Fitted:
    """One fitted parameter: value, its 95 % bounds lo and hi (arrays), held (the fit held it,
    lo = hi: knot times, a chart's centre: no interval) and counted (read by its count and
    range, more than LISTED_NUMBERS numbers, rather than listed).
    """

    value: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    held: bool
    counted: bool


def _fitted(value, ci: dict) -> _Fitted:
    """One fitted parameter's _Fitted from its value and 95 % bounds ci ({"lo", "hi"})."""
    value, lo, hi = (np.asarray(a, float) for a in (value, ci["lo"], ci["hi"]))
    return _Fitted(value, lo, hi, bool(np.all(lo == hi)), value.size > LISTED_NUMBERS)


#: A slow mode and a momentum read together as one rotor (_rotor_reading): the most their axes
#: may differ (deg), and the least share of the record the mode's period spans.
ROTOR_READING = (10.0, 0.5)


def _rotor_reading(expl: list[dict], duration: float | None) -> str | None:
    """The sentence that reads a flexible mode and an internal momentum of the explanation as one
    rotor, or None: where the mode's period spans at least ROTOR_READING[1] of the record
    (duration s; None: no reading) and its coupling lies within ROTOR_READING[0] deg of the
    momentum's axis (its varying form's) or direction. A mode's swing enters the body's
    equation as a momentum along its coupling, so the two together draw a momentum that rises
    and falls along that axis (a rotor spun up and braked over a 20-s record as
    0.5 (1 - cos 2 pi t / 20 s) is read so).
    """
    named = {e["name"]: e for e in expl}
    mode, momentum = named.get("flexible_mode"), named.get("internal_momentum")
    if mode is None or momentum is None or not duration:
        return None
    period = 2.0 * np.pi / float(mode["params"]["omega_n"])
    along = np.asarray(momentum["params"]["axis" if momentum["form"] == "varying" else "h"], float)
    coupling = np.asarray(mode["params"]["coupling"], float)
    norms = np.linalg.norm(along) * np.linalg.norm(coupling)
    if not norms > 0 or period < ROTOR_READING[1] * duration:
        return None
    angle = float(np.degrees(np.arccos(min(1.0, abs(along @ coupling) / norms))))
    if angle > ROTOR_READING[0]:
        return None
    axis = np.round(coupling / np.linalg.norm(coupling), 3).tolist()
    return (f"flexible_mode (period {period:.3g} s, {period / duration:.2g} of the record) and "
            f"internal_momentum lie along one body axis {axis} ({angle:.1f} deg apart): a mode's swing "
            "is a momentum along its coupling, so together they are a momentum that rises and falls "
            "along that axis, a rotor spinning up and down where the body has one.")


#: The damping ratio from which a fitted mode reads as dissipation (_damped_mode_reading):
#: 1/sqrt(2), where a second-order system stops amplifying any forcing (no resonant peak).
DISSIPATIVE_ZETA = 1.0 / np.sqrt(2.0)


def _damped_mode_reading(expl: list[dict]) -> str | None:
    """The sentence that reads a flexible mode of damping ratio at least DISSIPATIVE_ZETA as
    internal dissipation, or None. Such a mode has no resonance and sheds its energy within
    its slowest time constant while the body's angular momentum is kept: the physics of a nutation
    damper or a heavily damped slosh mass, of which internal_dissipation's torque is the
    quasi-steady limit (the mode keeps the internal mass's lag, which that torque leaves out).
    """
    mode = next((e for e in expl if e["name"] == "flexible_mode"), None)
    if mode is None or float(mode["params"]["zeta"]) < DISSIPATIVE_ZETA:
        return None
    zeta, omega = float(mode["params"]["zeta"]), float(mode["params"]["omega_n"])
    # the slowest decay rate of the mode's free motion: zeta omega while it oscillates, the slow
    # pole omega / r when overdamped
    rate = omega / pole_spread(zeta) if zeta > 1.0 else zeta * omega
    return (f"flexible_mode's damping ratio {zeta:.2g} is at or above 1/√2: the internal motion has "
            f"no resonance and its energy decays with a time constant of {0.5 / rate:.3g} s "
            "while the angular momentum is kept. Read it as internal dissipation: a damper or a "
            "heavily damped slosh mass (internal_dissipation is the same physics without the "
            "internal mass's lag).")


def _loaded_mode_reading(expl: list[dict]) -> str | None:
    """The sentence that reads flexible_mode's loaded form, or None: the moving part carries
    mass, so the inertia changes as it moves and the rotation loads it (a propellant mass
    pressed outwards, a panel bent back), which a mode that moves no mass leaves to a term
    beside it.
    """
    mode = next((e for e in expl if e["name"] == "flexible_mode" and e.get("form") == "loaded"), None)
    if mode is None:
        return None
    k = np.asarray(mode["params"]["inertia_rate"], float)
    size = float(np.abs(np.linalg.eigvalsh(matrix6(k))).max())
    return ("flexible_mode is loaded: the moving part carries mass, so the inertia changes by K eta "
            f"as it moves (K's largest principal value {size:.3g} √kg·m) and the rotation presses on "
            "it (w^T K w / 2), as on a propellant mass or an appendage of a rotating body.")


def _flight_reading(expl: list[dict]) -> str | None:
    """The sentence that reads aero_drag's flight form in the explanation as a throw, or None: the
    plate's normal, the launch speed and how far above the horizontal it was thrown.
    """
    flight = next((e for e in expl if e["name"] == "aero_drag" and e["form"] == "flight"), None)
    if flight is None:
        return None
    p = flight["params"]
    v0, down = np.asarray(p["launch_velocity"], float), np.asarray(p["gravity_direction"], float)
    speed = float(np.linalg.norm(v0))
    climb = float(np.degrees(np.arcsin(np.clip(-(v0 @ down) / speed, -1.0, 1.0)))) if speed > 0 else 0.0
    return (f"aero_drag's flight form reads the body as a flat plate of normal "
            f"{np.round(p['normal'], 3).tolist()} (body axes) thrown at {speed:.3g} m/s, {climb:.0f} deg "
            "above the horizontal, through still air: the air's torque follows the throw's speed "
            "and the plate's attitude to it.")


def _explanation_words(report: dict) -> str:
    """The compound explanation and what was left out, in sentences."""
    expl = report["explanation"]
    if not expl:
        text = "**Explanation:** no effect improves the fit significantly; the nominal model stands."
    else:
        parts = [f"{_label(e)} (adds delta BIC {e['delta_bic']:.1f})" for e in expl]
        text = ("**Explanation:** the nominal model leaves out " + "; then ".join(parts)
                + ". Its fitted parameters, with 95 % intervals, are in the table below.")
        for e in expl:
            cmp = e.get("inertia_vs_nominal")
            if cmp is not None:
                text += (f"\n\nThe inertia differs from the nominal: principal moments change by "
                         f"{np.round(cmp['percent_change'], 1).tolist()} % (ascending), principal "
                         f"axes turn by {np.round(cmp['axis_rotation_deg'], 1).tolist()} deg"
                         + ("" if cmp["scale_compared"] else
                            " (no torque or known momentum: shapes compared at the nominal's "
                            "trace)") + ".")
            for c in e["confounded_with"]:
                text += f"\n\n{e['name']} is confounded with {c['with']}: {c['reason']}."
        rotor = _rotor_reading(expl, report.get("duration_s"))  # (a hand-made report may lack it)
        text += f"\n\n{rotor}" if rotor else ""
        flight = _flight_reading(expl)
        text += f"\n\n{flight}" if flight else ""
        damped = _damped_mode_reading(expl)
        text += f"\n\n{damped}" if damped else ""
        loaded = _loaded_mode_reading(expl)
        text += f"\n\n{loaded}" if loaded else ""
    cmp = report.get("inertia_vs_nominal")
    if cmp is not None and cmp["delta_bic"] is not None:
        text += (f"\n\nYour model with its nominal inertia as given (the base of every effect but "
                 f"inertia_offset; report.json's `fit_before`) against the same model with the inertia "
                 f"fitted (`fit_inertia_fitted`): delta BIC {cmp['delta_bic']:.1f}; principal moments "
                 f"{np.round(cmp['percent_change'], 2).tolist()} % from the nominal's "
                 f"(ascending), matched axes turned by {np.round(cmp['axis_rotation_deg'], 2).tolist()} deg.")
    if _scale_loose(report):
        text += ("\n\nThe commanded torque or the known internal momentum fixes the inertia's scale only "
                 "loosely (relative sigma of the fitted trace "
                 + (f"{report['scale_sigma']:.2g}" if report["scale_sigma"] is not None else "unbounded")
                 + f", over {SCALE_SIGMA_IDENTIFIED:g}): the principal-moment ratios are firmer than the "
                 "absolute values, and every fitted torque (N·m), momentum (kg·m²/s) and damping "
                 "coefficient carries the trace's uncertainty.")
    if not report["scale_identified"]:
        text += ("\n\nNo commanded torque or known internal momentum: the data fix the inertia only up "
                 "to a common factor, "
                 + ("so the fitted torques, momenta and damping are in units of the sidecar's "
                    "nominal inertia and scale with it if it is wrong."
                    if report.get("inertia_nominal_given") else
                    "and with no nominal inertia in the sidecar its trace was set to "
                    f"{report['inertia_trace_assumed']:g} kg·m²: every fitted torque (N·m), "
                    "momentum (kg·m²/s) and damping coefficient scales with the unknown true "
                    "trace; multiply them by (true trace) / "
                    f"{report['inertia_trace_assumed']:g}."))
    elif not report.get("inertia_nominal_given"):  # fixed, up to an actuator's scale
        text += ("\n\nThe inertia's scale is fixed by the commanded torque and the known internal "
                 "momentum as logged: a torque c times the commanded one (an actuator scale) or a "
                 "momentum c times the logged one makes the true inertia c times the fitted one, and "
                 "with no nominal inertia in the sidecar the data cannot tell the two apart.")
    # only what the data supported alone: an effect no fit favours is in the table of every effect
    significant = {e["name"] for e in report.get("effects", []) if e["significant"]}
    left_out = {name: why for name, why in report["left_out"].items() if name in significant}
    if left_out:
        text += "\n\nLeft out of the explanation: " + "; ".join(
            f"{name} ({why})" for name, why in left_out.items()) + "."
    return text


def _ratios_words(fit: dict) -> str:
    ci = fit["principal_ratios_ci95"] or [[None, None]] * 3
    return ", ".join(f"{r:.3g}" + ("" if lo is None or hi - lo < 5e-4 else f" [{lo:.3g}, {hi:.3g}]")
                     for r, (lo, hi) in zip(fit["principal_ratios"], ci))


def _shape_words(report: dict) -> list[str]:
    """The inertia's shape before and after the explanation, with a warning where a ratio's 95 %
    interval is wider than RATIO_SPREAD: after the explanation and over twice the rigid fit's
    (the explanation's effects trade with the inertia), or already for the rigid fit (the record
    fixes the shape poorly).
    """
    before, after = report["fit_before"], report["fit_after"]
    if not (before.get("valid") and after.get("valid")):  # a fit not followed, or no ratios written
        return []
    words = [f"- principal-moment ratios (95 % intervals): rigid fit {_ratios_words(before)}; "
             f"with the explanation {_ratios_words(after)}"]
    if before["principal_ratios_ci95"] is None or after["principal_ratios_ci95"] is None:
        return words
    rigid = np.ptp(np.array(before["principal_ratios_ci95"]), axis=1)
    width = np.ptp(np.array(after["principal_ratios_ci95"]), axis=1)
    if report["explanation"] and np.any((width > RATIO_SPREAD) & (width > 2.0 * rigid)):
        momentum = any(e["name"] == "internal_momentum" for e in report["explanation"])
        words.append("- **the explanation leaves the inertia's shape poorly determined** (a ratio's "
                     f"95 % interval is wider than {RATIO_SPREAD:g} and than twice the rigid fit's): "
                     "its effects trade with the inertia"
                     + (" (about a near-steady spin, a momentum along the spin axis changes the "
                        "nutation as the moments do)" if momentum else "")
                     + "; do not read the body's shape from this fit")
    elif np.any(rigid > RATIO_SPREAD):
        words.append(f"- the record fixes the inertia's shape poorly: a ratio's 95 % interval is wider "
                     f"than {RATIO_SPREAD:g} already for the rigid fit")
    return words


def _noise_words(report: dict) -> list[str]:
    """A warning where the noise level read from the data reads high (_noise_reads_high), or the
    sidecar's level disagrees with the samples' (sensors.stated_noise_note); after the line that
    the samples' quantisation was added to the sidecar's level, where it was, the one that
    the gyro's rounding raised the margin of the effects (fit.rounding_floors), where it did, and
    the one that the intervals count the rounding (fit.lattice_spread), where they do.
    """
    noise = report.get("noise", {})  # (a report written before the keys existed has neither)
    said = [f"- {noise['quantisation']}"] if noise.get("quantisation") else []
    if noise.get("rounding_floor"):
        runs = [f"{r:.1f}" for r in noise["rounding_runs"] if r > 0]
        top = sorted(noise["rounding_floor"].items(), key=lambda kv: -kv[1])[:3]
        said.append("- **the gyro reads the rate coarser than its motion and noise move it** (its "
                    f"samples repeat in runs of {', '.join(runs)} on average): the rounding error "
                    "follows the rate, and fits gain from tracing it. Each effect must beat, besides "
                    "the margin, the most its fit gains on the rounded nominal model alone ("
                    + ", ".join(f"`{name}` {gain:.0f}" for name, gain in top)
                    + (", ..." if len(noise["rounding_floor"]) > 3 else "")
                    + "; `noise.rounding_floor`): smaller effects than the rounding hides are not "
                    "claimed")
    if noise.get("lattice_refits"):
        said.append("- the intervals (the principal-moment ratios', the effects' parameters') count the "
                    "rounding: the spread of the fit's refits on its own prediction read on the gyro's "
                    f"lattice ({noise['lattice_refits']} of {LATTICE_REPLAYS} replays, shifted at random, "
                    "the noise beneath the step added) is added to their covariance")
    if noise.get("sidecar_disagrees"):
        return said + ["- **the sidecar's noise level disagrees with the data's**: "
                       f"{noise['sidecar_disagrees']}"]
    if not noise.get("read_high"):
        return said
    return said + ["- **the noise level read from the data reads high**: the best fit leaves "
            f"{_fmt(report['fit_after']['rms_over_noise'])} of it, under {NOISE_READ_HIGH:g} on every "
            "axis: motion fast for the sampling passed for noise (give the gyro's `gyro_sigma` in a "
            "sidecar); every rms / noise here reads that much low, and the noise-based flags "
            "(beyond the catalogue, unexplained) are that much lenient. The selection does not depend "
            "on it"]


def _frame_words(report: dict) -> list[str]:
    """The line on a gyro frame that reads left-handed (mirrored_frame), or none."""
    frame = report["gyro_frame_mirrored"]
    if not frame:
        return []
    return [f"- **the gyro's frame reads left-handed**: with its x and y columns swapped (or one axis's "
            f"sign flipped) the rates fit a rigid body to {_fmt(frame['rms_over_noise'])} times the noise "
            f"(principal ratios {_fmt(frame['principal_ratios'])}), {frame['delta_bic']:.0f} better in BIC "
            "than the explanation below: check the order and signs of the gyro's axes before reading "
            "the effects"]


def _clip_words(report: dict) -> list[str]:
    """A line where an axis is held at its extreme in a record's first or last samples
    (prepare.clips_at_the_ends: not left out, a rate may start or end at its peak).
    """
    ends = report.get("clipped_at_ends")  # absent from reports of older versions
    if not ends:
        return []
    return [f"- **held at its extreme at the record's end**: {'; '.join(ends)}: {CLIP_ADVICE}"]


def _invariants_words(inv: dict) -> str:
    """The invariants' drifts and their reading of the missing torque, in words."""
    if not inv.get("applicable"):
        return f"Invariants: not read ({inv.get('reason', 'not applicable')})."

    def drift(key: str, name: str) -> str:
        rel = inv[key]["relative_drift"]
        return f"{name} {'grows' if rel > 0 else 'falls'} {abs(rel):.1%} (z {inv[key]['z']:.0f})"

    head = (f"Invariants (torque-free they hold; read with the inertia of `fit_after`): over the record "
            f"{drift('momentum', '|H|')} and {drift('energy', 'the rotational energy')}")
    reading = inv["reading"]
    plain = {
        "none": "neither drifts beyond the noise: no torque acts that these rows would show.",
        "internal": "the energy drifts and |H| is kept: physics inside the body (dissipation, "
                    "a moving part), not an external torque.",
        "adds to the rotation": "a torque adds to the rotation: no drag does that.",
        "drains |H|, energy kept": "|H| falls while the energy holds: an external torque, neither "
                                   "a drag against the rates nor one against the angular momentum.",
        NOT_READ: "too little rotation, or a known internal momentum against it, to read the drifts.",
    }
    if reading in plain:
        return f"{head}: {plain[reading]}"
    if reading == "uncertain":
        both = inv["readings"]
        return (f"{head}: what this says of the missing torque depends "
                f"on the inertia, which neither fit pins (both leave more than noise): with the "
                f"rigid fit's it reads {both['rigid fit']!r}, with the explanation's "
                f"{both['explanation']!r}.")
    along_h, along_w = inv["against_momentum_ratio"], inv["against_rates_ratio"]
    refs = (f"a torque against the angular momentum (tau = -k H; without internal momentum a drag "
            f"-k J w, every motion slowed alike) gives {along_h:.2f} here, one against the rates "
            f"(tau = -c w) {along_w:.2f}")
    if abs(along_w / along_h - 1) < 0.05:
        refs += " (the two lie close: the rotation stays near a principal axis)"
    verdict = {
        "drains the energy beyond a drag": "faster than either: dissipation inside the body besides",
        "drains |H| beyond a drag": "slower than either: a torque across the rotation",
    }.get(reading, f"the missing torque reads as the one {reading}")
    return (f"{head}: the energy falls {inv['energy_per_momentum']:.2f} times as fast as |H|. "
            f"{refs[0].upper()}{refs[1:]}: {verdict}.")


def _beyond_words(report: dict) -> list[str]:
    """A warning where the explanation leaves the residual over BEYOND_CATALOGUE times the noise,
    names an implausible effect, or left out an added effect that did not predict held-out rows.
    """
    if not report.get("beyond_catalogue"):  # (a report written before the key existed: none)
        return []
    before, after = report["fit_before"], report["fit_after"]
    if not after["valid"]:
        return ["- **beyond the catalogue**: the best fit is not a valid fit: the recording holds "
                "physics the catalogue cannot model"]
    worst = max(after["rms_over_noise"])
    odd = [e for e in report["explanation"] if e.get("implausible")]
    refused = report.get("refused_implausible") or []
    unpredictive = report.get("unpredictive") or []
    if unpredictive and not (odd or refused) and worst <= BEYOND_CATALOGUE:
        return ["- **beyond the catalogue**: " + "; ".join(
            f"`{u['name']}` lowers the misfit on the rows it is fitted to, but fits the stretches "
            f"held out in turn {u['held_out_ratio']:.2f}x as badly (time-blocked cross-validation)"
            for u in unpredictive)
            + f", so it is left out: the explanation leaves {_fmt(after['rms_over_noise'])} times "
            "the noise, a misfit with structure that no effect of the catalogue predicts"]
    if (odd or refused) and worst <= BEYOND_CATALOGUE:
        return ["- **beyond the catalogue**: " + "; ".join(
            [f"`{e['name']}` is not physics this body or sensor plausibly has ({e['implausible']})"
             for e in odd] + [f"`{r['name']}` would improve the fit (delta BIC {r['delta_bic']:.1f}) but is "
                              f"not physics this body or sensor plausibly has ({r['why']}), and is left out "
                              "of the explanation" for r in refused])
            + ": what it fits is physics the catalogue lacks, or a distortion of the record, not that "
            "effect"]
    words = (f"- **beyond the catalogue**: the best fit still leaves {_fmt(after['rms_over_noise'])} "
             f"times the noise (over {BEYOND_CATALOGUE:g}): the recording holds physics the catalogue "
             "lacks" + "".join(f"; `{r['name']}` would fit it better (delta BIC {r['delta_bic']:.1f}) "
                               f"but is not physics this body or sensor plausibly has ({r['why']})"
                               for r in refused))
    if not report["explanation"]:
        return [words + ", and none of its effects accounts for any of it"]
    return [words + f"; the explanation takes the worst axis from {max(before['rms_over_noise']):.3g} to "
            f"{worst:.3g} times the noise: read its effects as the catalogue's closest approximation "
            "of what is missing, not necessarily all of it, and what it leaves may have pulled "
            "them off"]


def _label(e: dict) -> str:
    """An explanation entry's name as its reading allows (:data:`READINGS`): the named physics,
    the physics if the body carries the part it needs, or what the fitted terms do.
    """
    model = REGISTRY.get(e["name"])
    form = [f"{e['form']} form"] if e.get("form") else []
    said = e.get("reading", "physics")
    if model is not None and e.get("implausible"):
        what = model.as_fitted.get(e.get("form") or "", model.as_fitted.get("", "a term"))
        return f"{what} (fitted as `{e['name']}`{', ' + form[0] if form else ''}; {e['implausible']})"
    if model is None or said == "physics":
        return f"`{e['name']}`" + (f" ({form[0]})" if form else "")
    what = model.as_fitted.get(e.get("form") or "", model.as_fitted[""])
    if said == "if_carried":
        return f"`{e['name']}` ({'; '.join(form + [f'if {model.carried_words()}'])}; else {what})"
    return f"{what} (`{e['name']}`{', ' + form[0] if form else ''}; the sidecar says {model.lacked_words()})"


def _verdict(report: dict) -> str:
    """Whether the rigid model explains the record, what is missing, where, and how much."""
    before, after = report["fit_before"], report["fit_after"]
    worst_before, worst_after = max(before["rms_over_noise"]), max(after["rms_over_noise"])
    names = [_label(e) for e in report["explanation"]]
    if not report["mismatch_detected"]:
        text = (f"The model explains the record: its residuals are at the gyro's noise (worst axis "
                f"{worst_before:.3g} times it), and no effect of the catalogue improves the fit "
                "significantly.")
    elif not names:
        text = (f"The model misses something (worst axis {worst_before:.3g} times the noise), and no "
                "effect of the catalogue accounts for it.")
    else:
        text = (f"The model misses physics: {' and '.join(names)} "
                f"{'explains' if len(names) == 1 else 'explain'} the record, taking the worst axis from "
                f"{worst_before:.3g} to {worst_after:.3g} times the gyro's noise.")
    if report["locations"]:
        text += " The misfit shows " + "; ".join(
            f"over t = {w['t_start']:.3g}–{w['t_end']:.3g} s on {', '.join(w['axes'])}"
            for w in report["locations"]) + "."
    return text


def _physics_table(report: dict) -> list[str]:
    """The explanation's fitted parameters, one row each, with 95 % intervals and units."""
    if not report["explanation"]:
        return []
    rows = ["| effect | parameter | value | 95 % interval | unit |", "|---|---|---|---|---|"]
    for e in report["explanation"]:
        units = REGISTRY[e["name"]].units if e["name"] in REGISTRY else {}
        for key, value in e["params"].items():
            f = _fitted(value, e["ci95"][key])
            if f.counted:
                shown = f"{f.value.size} values, {f.value.min():.4g} to {f.value.max():.4g}"
                interval = "" if f.held else f"± up to {np.max(f.hi - f.lo) / 2:.3g}"
            else:
                shown = str(_significant(value))
                interval = "held" if f.held else f"{_significant(f.lo)} to {_significant(f.hi)}"
            rows.append(f"| {e['name']} | {key} | {shown} | {interval} | {units.get(key, '')} |")
    return rows


def _next_steps(report: dict) -> list[str]:
    """What a user does next, read from the verdict."""
    steps = []
    plausible = [e for e in report["explanation"] if not e.get("implausible")]
    if plausible:
        names = ", ".join(f"`{e['name']}`" for e in plausible)
        steps.append(f"Add {names} to the simulation with the fitted values above (report.json holds "
                     "them in full), then diagnose another recording of the body: physics that is "
                     "there is found again.")
    if report["ambiguous"] or any(e["confounded_with"] for e in report["explanation"]):
        steps.append("Effects this record cannot tell apart are named above: a recording with more "
                     "varied rates (another spin axis, a faster or a longer tumble) separates them.")
    implausible = ([(e["name"], e["implausible"]) for e in report["explanation"] if e.get("implausible")]
                   + [(r["name"], r["why"]) for r in report.get("refused_implausible") or []])
    if implausible:
        steps.append("Beyond the plausible range: "
                     + "; ".join(f"`{name}` ({why})" for name, why in implausible)
                     + ". Look for what else moves the rates so: the sensor's mounting, clock or "
                     "saturation, or a part of the body the catalogue does not hold.")
    if (report.get("beyond_catalogue") and not implausible) or report.get("unexplained_residual"):
        steps.append(f"The explanation leaves {max(report['fit_after']['rms_over_noise']):.3g} times the "
                     "noise on its worst axis: look at the located windows and the residual plot; "
                     "report.json's `sparse_terms` lists the torque terms a sparse regression finds in "
                     "what is left.")
    if not report["scale_identified"]:
        steps.append("This record does not fix the inertia's scale: a recording with a known torque "
                     "or a rotor's changing momentum does.")
    elif _scale_loose(report):
        steps.append("The scale is fixed only loosely: a stronger or longer torque, or a larger change "
                     "of the known momentum, fixes it better.")
    if not steps:
        steps.append("Nothing is missing that this record can show; a recording with a larger or "
                     "another excitation tests the model further.")
    return [f"- {step}" for step in steps]


def _scale_loose(report: dict) -> bool:
    """The record fixes the scale, but its trace's relative sigma is unbounded or over
    SCALE_SIGMA_IDENTIFIED.
    """
    if "scale_sigma" not in report:  # a report that does not carry the sigma says nothing of it
        return False
    sigma = report["scale_sigma"]
    return bool(report["scale_identified"]) and (sigma is None or sigma > SCALE_SIGMA_IDENTIFIED)


def markdown(report: dict, plots: list[str]) -> str:
    """A summary of one report for people: the verdict first, the fitted physics with intervals
    and units, the inertia, the record, every effect tried and what to do next. The raw values
    stay in report.json.
    """
    lines = [f"# Diagnosis of {report['recording']}", "", "## Verdict", "", _verdict(report),
             *_beyond_words(report)]
    lines += ["", "## What is missing", "", _explanation_words(report), "", *_physics_table(report)]
    told = {(e["name"], c["with"]) for e in report["explanation"] for c in e["confounded_with"]}
    for a in report["ambiguous"]:
        if tuple(a["effects"]) not in told:  # the explanation's words already say it
            lines.append(f"- cannot be told apart: {', '.join(a['effects'])}: {a['reason']}")
    lines += ["", "## The inertia", "", *_shape_words(report)]
    lines += ["", "## The record", "",
              f"- samples: {report['samples']}, duration {report['duration_s']:.2f} s",
              f"- gyro noise: {_significant(report['gyro_sigma'], 3)} rad/s "
              f"({report['gyro_sigma_source']})", *_noise_words(report),
              f"- fit rms / noise before: {_fmt(report['fit_before']['rms_over_noise'])}, "
              f"after: {_fmt(report['fit_after']['rms_over_noise'])}",
              *_clip_words(report), *_frame_words(report)]
    if report.get("retimed"):
        lines.append(f"- {retimed_note(report['retimed'])}")
    window = report.get("free_flight_window")
    note = window and window_note(window["t_start"], window["t_end"], window["source"])
    if note:
        lines.append(f"- {note}")
    lines += ["", "## Every effect tried", "",
              "Each effect fitted alone, by how much it improves the BIC (over 10: very strong "
              f"evidence), best first; effects within {TIE_BIC} in BIC of the best left are a "
              "tie, listed in the catalogue's order. Its fitted values are in report.json.", "",
              "| effect | delta BIC | significant |", "|---|---|---|"]
    for e in report["effects"]:
        delta = "no valid fit" if e["delta_bic"] is None else f"{e['delta_bic']:.1f}"
        lines.append(f"| {e['name']} | {delta} | {'yes' if e['significant'] else 'no'} |")
    if report["skipped_effects"]:
        lines.append("")
    for name, why in report["skipped_effects"].items():
        lines.append(f"- not tested: {name}: {why}")
    lines += ["", "## Invariants", "", _invariants_words(report["invariants"])]
    lines += ["", "## What to do next", "", *_next_steps(report)]
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(lines) + "\n"
