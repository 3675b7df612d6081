"""The sensor model: noise statistics, saturation, quantisation to the bit depth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from catenary_linescan.simulator.rig import SimRig
from catenary_linescan.simulator.sensor import expose


def test_quantised_to_the_bit_depth(demo_rig: SimRig) -> None:
    cam8 = demo_rig.cameras[0]
    cam12 = dataclasses.replace(cam8, bit_depth=12, gain_dn_per_e=4095 / cam8.full_well_e)
    electrons = np.linspace(0.0, 1.5 * cam8.full_well_e, 4096, dtype=np.float32)[None, :]
    for cam, dtype in ((cam8, np.uint8), (cam12, np.uint16)):
        lines = expose(electrons, cam, np.random.default_rng(0))
        assert lines.dtype == dtype
        assert int(lines.max()) == cam.max_dn  # saturates at the top of the range
        clean = expose(electrons, cam, None)
        expected = np.clip(
            np.rint(electrons * cam.gain_dn_per_e + cam.black_level_dn), 0, cam.max_dn
        )
        np.testing.assert_array_equal(clean, expected.astype(dtype))
    # a 12-bit camera resolves what an 8-bit one cannot
    assert (
        np.unique(expose(electrons, cam12, None)).size
        > 16 * np.unique(expose(electrons, cam8, None)).size / 2
    )


def test_full_well_saturates_before_the_adc(demo_rig: SimRig) -> None:
    # a 16-bit ADC with room above the full well: the charge still clips at full well
    cam = dataclasses.replace(
        demo_rig.cameras[0], bit_depth=16, gain_dn_per_e=1.0, read_noise_e=0.0, black_level_dn=0
    )
    lines = expose(np.full((4, 64), 5.0 * cam.full_well_e, np.float32), cam, None)
    assert np.all(lines == cam.full_well_e)


@pytest.mark.parametrize("mean_e", [3.0, 40.0, 5000.0])
@pytest.mark.parametrize("read_e", [0.2, 20.0])
def test_shot_and_read_noise_statistics(demo_rig: SimRig, mean_e: float, read_e: float) -> None:
    """Poisson shot noise plus Gaussian read noise: mean λ, variance λ + σr² (in electrons)."""
    cam = dataclasses.replace(
        demo_rig.cameras[0],
        bit_depth=16,
        gain_dn_per_e=8.0,  # fine quantisation: 1/8 e- per grey level
        full_well_e=8000.0,
        read_noise_e=read_e,
        black_level_dn=2000.0,
        prnu=0.0,
    )
    electrons = np.full((200, 1000), mean_e, dtype=np.float32)
    lines = expose(electrons, cam, np.random.default_rng(7)).astype(np.float64)
    charge = (lines - cam.black_level_dn) / cam.gain_dn_per_e
    sigma = np.sqrt(mean_e + read_e**2)
    assert charge.mean() == pytest.approx(mean_e, abs=5.0 * sigma / np.sqrt(charge.size) + 0.01)
    assert charge.var() == pytest.approx(sigma**2, rel=0.02)
    if read_e < 1.0 and mean_e < 10.0:
        # a quiet read-out at few electrons shows the Poisson law's discreteness
        frac = charge - np.round(charge)
        assert np.mean(np.abs(frac) < 0.25) > 0.6


def test_prnu_is_a_fixed_pattern(demo_rig: SimRig) -> None:
    cam = dataclasses.replace(demo_rig.cameras[0], bit_depth=16, gain_dn_per_e=1.0)
    from catenary_linescan.simulator.sensor import prnu_map

    a = prnu_map(cam)
    assert np.array_equal(a, prnu_map(cam))
    assert a.std() == pytest.approx(cam.prnu, rel=0.1)
