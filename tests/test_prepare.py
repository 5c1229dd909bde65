"""The preparation layer (prepare.py): clipped samples, impulses at a record's ends, the noise
level, and a record prepared once for every product."""

import dataclasses

import numpy as np
import pytest

from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.prepare import (
    clip_hint,
    clips_at_the_ends,
    end_impulses,
    prepared,
    rate_impulses,
    saturated_samples,
)
from inertia_gym.recordings import Recording
from inertia_gym.scenario import Scenario
from inertia_gym.sensors import quantisation_step


def test_end_impulses_keeps_the_rows_between_the_last_jump_near_the_start_and_the_first_near_the_end():
    z = np.random.default_rng(0).normal(size=(200, 3))
    assert end_impulses(z) == (0, 200)
    jolted = z.copy()
    jolted[:3] += 40.0 * np.arange(3, 0, -1)[:, None]  # rows 0-2 fall back by 40 per row
    jolted[190:] += 50.0  # a step at row 190
    assert end_impulses(jolted) == (3, 190)
    # a smooth drift to 60x the noise at the end stays; a jump in the middle is no end impulse
    drift = z + np.linspace(0.0, 60.0, 200)[:, None] ** 2 / 60.0
    assert end_impulses(drift) == (0, 200)
    middle = z.copy()
    middle[100:] += 50.0
    assert end_impulses(middle) == (0, 200)
    # a jump across a segment boundary is not an impulse; short or non-finite input keeps all
    same = np.ones(199, bool)
    same[189] = False
    assert end_impulses(jolted, same) == (3, 200)
    assert end_impulses(jolted[:19]) == (0, 19)
    assert end_impulses(np.where(np.arange(200)[:, None] == 5, np.nan, z)) == (0, 200)


def test_a_coarsely_quantized_gyro_is_not_taken_for_a_clipped_one_and_a_clipped_one_still_is():
    """A slow spin read by a gyro quantized at 4x its noise repeats its extreme values at smooth
    peaks (a rule that counts repeats alone takes 125 of 1201 rows as clipped, which identify
    would leave out with a false note); clipped at 0.3 rad/s it sits there, and is."""
    sc = Scenario(omega0=(0.05, 0.03, 0.5), tau_max=50.0, gyro_sigma=0.0005)
    rec, _ = simulate_recording(sc, 120.0, None, seed=3, sample_dt=0.1, torque=False)
    quantized = np.round(rec.w / 0.002) * 0.002
    assert not saturated_samples(dataclasses.replace(rec, w=quantized)).any()
    clipped = quantized.copy()
    clipped[:, 1] = np.clip(quantized[:, 1], -0.3, 0.3)
    flagged = saturated_samples(dataclasses.replace(rec, w=clipped))
    np.testing.assert_array_equal(flagged[:, 1], np.abs(quantized[:, 1]) >= 0.3)
    assert not flagged[:, [0, 2]].any()


#: A thrown device's principal moments (kg m^2), diagonal.
DEVICE = ((3e-4, 0.0, 0.0), (0.0, 4e-4, 0.0), (0.0, 0.0, 5e-4))


def _free_spin(omega0, dt, duration, seed, sigma=0.001):
    """A torque-free device read every dt s with gyro noise sigma rad/s (full precision)."""
    sc = Scenario(inertia_true=DEVICE, inertia_guess=DEVICE, omega0=omega0, dt=dt, gyro_sigma=sigma,
                  tau_max=1e-4)
    return simulate_recording(sc, duration, None, seed=seed, torque=False)[0]


@pytest.mark.parametrize("levels_per_sigma", [2.0, 8.0])
def test_a_gyro_read_in_coarse_steps_is_clipped_only_where_it_is_cut_while_still_climbing(levels_per_sigma):
    """A device flipping about its intermediate axis, read at 400 Hz in steps of 2 or 8 noise
    sigmas, and a slow spin read every 0.1 s in steps of 30 sigmas (its spin axis on one or two
    levels): no sample is clipped. Taking an extreme level read 3x as often as the next for a
    clip would take 7 samples of the first at 8 sigmas and the whole spin axis of the second
    (1201 of 1201 rows left out). The lattice of the first is read at 2 sigmas too (the
    one-step gaps are rare where the rate sweeps fast: the least recurring gap alone reads none
    on one axis). Each clipped at
    70 % of an axis's peak (the axes whose peak lies inside the record), that axis is clipped
    exactly there and the others not."""
    flip = _free_spin((2.0, 15.0, 1.0), 0.0025, 2.0, seed=3)
    step = levels_per_sigma * 0.001
    coarse = np.round(flip.w / step) * step
    np.testing.assert_allclose(saturated_samples(dataclasses.replace(flip, w=coarse)), False)
    np.testing.assert_allclose(quantisation_step(coarse), step, rtol=1e-6)
    for axis in (0, 2):  # the intermediate axis peaks at the record's ends
        top = 0.7 * np.abs(coarse[:, axis]).max()
        clipped = coarse.copy()
        clipped[:, axis] = np.clip(coarse[:, axis], -top, top)
        flagged = saturated_samples(dataclasses.replace(flip, w=clipped))
        np.testing.assert_array_equal(flagged[:, axis], np.abs(coarse[:, axis]) >= top)
        assert not np.delete(flagged, axis, axis=1).any()
    # a full scale in the sidecar: an int16 gyro's rails (+FS - step, -FS) are clipped, a peak
    # 3 steps under the full scale is not (a band from 0.999 of it takes 19 samples of a peak at
    # 99.93 %, 23 steps under, as clipped)
    under = {"gyro_full_scale_rad_s": np.abs(coarse).max() + 3 * step}
    assert not saturated_samples(dataclasses.replace(flip, w=coarse, meta=under)).any()
    full = np.round(0.7 * np.abs(coarse[:, 0]).max() / step) * step
    railed = coarse.copy()
    railed[:, 0] = np.clip(coarse[:, 0], -full, full - step)
    flagged = saturated_samples(dataclasses.replace(flip, w=railed, meta={"gyro_full_scale_rad_s": full}))
    rails = (coarse[:, 0] > full - 1.5 * step) | (coarse[:, 0] < 0.5 * step - full)
    np.testing.assert_array_equal(flagged[:, 0], rails)
    slow = _free_spin((0.05, 0.03, 0.5), 0.1, 120.0, seed=int(levels_per_sigma))
    levels = np.round(slow.w / 0.03) * 0.03
    assert np.unique(levels[:, 2]).size <= 2
    assert not saturated_samples(dataclasses.replace(slow, w=levels)).any()


def test_a_clip_at_both_ends_only_is_said_not_left_out():
    """An axis clipped at 8 rad/s only in its first and last 103 samples, read in steps of 2 noise
    sigmas: a run with one side shows no clip by itself (a rate may start at its peak), so
    nothing is left out, but the axis and its ends are named for identify's misfit sentences (a
    device so read is refused at 1.1e3 times the noise, and the sentence names the clipping);
    with the full scale given they are clipped and nothing more is said; unclipped, nothing
    is."""
    rng = np.random.default_rng(0)
    t = np.arange(1001) / 500.0
    w = np.stack([4.0 + 5.0 * np.cos(np.pi * t), 3.0 * np.sin(np.pi * t), 1.0 + 0.5 * t], 1)
    coarse = np.round((w + rng.normal(0.0, 0.002, w.shape)) / 0.004) * 0.004
    clipped = coarse.copy()
    clipped[:, 0] = np.minimum(coarse[:, 0], 8.0)
    assert not saturated_samples(Recording(t, clipped)).any()
    assert clips_at_the_ends(Recording(t, clipped)) == ["the x axis reads 8 rad/s in its first 103 samples",
                                                          "the x axis reads 8 rad/s in its last 103 samples"]
    assert "gyro_full_scale_rad_s" in clip_hint(Recording(t, clipped))
    given = Recording(t, clipped, meta={"gyro_full_scale_rad_s": 8.0})
    at_rail = clipped[:, 0] > 8.0 - 1.5 * 0.004
    np.testing.assert_array_equal(saturated_samples(given)[:, 0], at_rail)
    assert clips_at_the_ends(given) == []
    assert clips_at_the_ends(Recording(t, coarse)) == [] and clip_hint(Recording(t, coarse)) == ""


def test_the_rates_locate_a_catch_at_a_records_end_and_keep_a_smooth_record():
    rng = np.random.default_rng(1)
    t = np.arange(2000) * 2.5e-4
    w = np.stack([10 * np.cos(3 * t), 5 * np.sin(3 * t), 2 + t], 1) + 0.01 * rng.normal(size=(2000, 3))
    sigma = np.full(3, 0.01)
    assert rate_impulses(w, sigma) == (0, 2000)
    caught = w.copy()
    caught[1950:] += np.linspace(0, 30, 50)[:, None] ** 2  # a catch: the rates bend hard at the end
    start, stop = rate_impulses(caught, sigma)
    assert start == 0 and 1900 <= stop <= 1952


def test_a_prepared_record_leaves_out_an_end_impulse_and_says_so():
    sc = Scenario(omega0=(2.0, 15.0, 1.0), dt=0.0025, gyro_sigma=0.001)
    rec, _ = simulate_recording(sc, 1.0, None, seed=2, torque=False)
    jolted = rec.w.copy()
    jolted[-20:] += np.linspace(0, 40, 20)[:, None] ** 1.5
    prep = prepared(dataclasses.replace(rec, w=jolted, meta={"gyro_sigma": 0.001}))
    assert prep.kept[1] < rec.t.size and prep.rec.t.size == prep.kept[1] - prep.kept[0]
    assert any("impulse" in n for n in prep.notes)
    np.testing.assert_allclose(prep.sigma, 0.001, rtol=0.05)
    clean = prepared(dataclasses.replace(rec, meta={"gyro_sigma": 0.001}))
    assert clean.kept == (0, rec.t.size) and not any("impulse" in n for n in clean.notes)
    assert clean.usable.all()


def test_rows_of_a_prepared_record_keep_its_noise_level_and_count_kept_rows_from_the_original():
    rec, _ = simulate_recording(Scenario(), 20.0, seed=1, sample_dt=0.05)
    prep = prepared(rec)
    part = prep.rows(10, 50)
    assert part.rec.t.size == part.usable.size == 40
    np.testing.assert_array_equal(part.rec.w, prep.rec.w[10:50])
    np.testing.assert_array_equal(part.level, prep.level)
    assert part.kept == (prep.kept[0] + 10, prep.kept[0] + 50)


def test_rates_far_under_the_gyro_s_stated_noise_are_a_body_that_does_not_rotate():
    """Smooth rates under a fifth of the stated gyro noise, turning the body by a fraction of a
    radian: the data alone read them as clean motion, but the gyro cannot have resolved them, so
    the record is refused in one line."""
    from inertia_gym.errors import RecordingError
    from inertia_gym.prepare import check_recording

    t = np.linspace(0.0, 10.0, 501)
    w = 2e-2 * np.stack([np.sin(t), np.cos(t), 0.5 * np.sin(0.3 * t + 1.0)], axis=1)
    with pytest.raises(RecordingError, match="does not rotate"):
        check_recording(Recording(t, w, meta={"gyro_sigma": 0.03}))
    check_recording(Recording(t, 1e2 * w, meta={"gyro_sigma": 0.03}))  # 2 rad/s: it turns
