"""The least-squares describing function: any stretch, the Fourier method's on whole periods.

Independent answers: the Fourier method itself on whole periods (there the fitted
sinusoids are orthogonal, so the coefficients are the transform's bins to rounding,
1e-9), the precision model's exact frequency response on a noise-free loop (the
Fourier test's tolerances: 0.2 dB, one sample's lag of phase), and under remnant the
error the signal-to-noise ratios promise.
"""

import re
import warnings

import numpy as np
import pytest

from manualcontrol.envs.elements import Integrator
from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.pilots import Pilot, make_model, simulate

HUMAN_SI = dict(K_p=3.0, K_v=0.0, tau_v=0.25, omega_nms=12.0, zeta_nms=0.5)
MODEL = make_model("precision")


def _simulate(**options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # K_p 3 lies above thesis Table I's range: humans do
        return simulate(Pilot("precision", HUMAN_SI, **options.pop("pilot", {})), **options)


@pytest.fixture(scope="module")
def clean_run():
    return _simulate(element=Integrator(1.0), forcing="vanderel-bw4")


@pytest.fixture(scope="module")
def remnant_runs():
    return [
        _simulate(
            element=Integrator(1.0),
            forcing="vanderel-bw4",
            seed=seed,
            pilot={"remnant": "vertregt2020-SI"},
        )
        for seed in range(4)
    ]


def test_on_whole_periods_it_is_the_fourier_method(remnant_runs):
    run = remnant_runs[0]
    fourier = describing_function(run)
    fitted = describing_function(run, method="least-squares")
    assert fitted.window == fourier.window and fitted.periods == fourier.periods == 1
    for name in ("pilot", "snr", "snr_injected", "gain_spread_db", "element_measured"):
        np.testing.assert_allclose(getattr(fitted, name), getattr(fourier, name), rtol=1e-9)
    for name, values in fourier.lines.coefficients.items():
        np.testing.assert_allclose(
            fitted.lines.coefficients[name], values, rtol=0, atol=1e-9 * np.abs(values).max()
        )
    assert fitted.remnant_share == pytest.approx(fourier.remnant_share, rel=1e-6)
    assert fitted.crossover_frequency == pytest.approx(fourier.crossover_frequency, rel=1e-9)
    assert fourier.to_dict()["method"] == "fourier"
    assert fitted.to_dict()["method"] == "least-squares"


@pytest.mark.parametrize("seconds", [45.0, 60.0, 100.0])
def test_a_stretch_shorter_than_a_period_gives_the_pilot(clean_run, seconds):
    stretch = clean_run.slice_time(clean_run.t[0], clean_run.t[0] + seconds)
    measured = describing_function(stretch, method="least-squares")
    expected = MODEL.frequency_response(HUMAN_SI, measured.frequencies, "e")
    ratio = measured.pilot / expected
    np.testing.assert_array_less(np.abs(20 * np.log10(np.abs(ratio))), 0.2)
    np.testing.assert_array_less(np.abs(np.angle(ratio)), measured.frequencies * 0.01 + 1e-3)
    assert measured.periods == 0
    assert measured.window == pytest.approx((0.0, seconds))
    with pytest.raises(ValueError, match="shorter than one forcing period"):
        describing_function(stretch)  # the Fourier method needs a whole period


@pytest.mark.parametrize(("seconds", "ceiling"), [(90.0, 1.4), (60.0, 2.0)])
def test_short_stretch_snr_predicts_the_error_under_remnant(remnant_runs, seconds, ceiling):
    # as for the Fourier method: the error scaled by sqrt(snr_injected) behaves like the
    # modulus of a unit complex Gaussian (median 0.83) where the SNR is usable. On part
    # of a 120-s period neighbouring lines lie under a bin apart, and their coefficients'
    # variance is inflated (without the inflation the median is 1.4 at 90 s, 2.4 at 60 s;
    # with it 1.2 and 1.4). Half a period reads the noise of the clustered low lines
    # further from them, hence the looser ceiling there.
    scaled = []
    for run in remnant_runs:
        stretch = run.slice_time(run.t[0], run.t[0] + seconds)
        measured = describing_function(stretch, method="least-squares")
        truth = MODEL.frequency_response(HUMAN_SI, measured.frequencies, "e")
        error = np.abs(np.log(measured.pilot / truth))
        usable = measured.snr_injected >= 4.0
        scaled.append((error * np.sqrt(measured.snr_injected))[usable])
    assert 0.5 < np.median(np.concatenate(scaled)) < ceiling


def test_bad_inputs_are_named(clean_run):
    with pytest.raises(ValueError, match="method must be one of 'fourier', 'least-squares'"):
        describing_function(clean_run, method="lsq")
    bare = clean_run.with_metadata(forcing=None)
    # with the period alone the lines are read off the recorded forcing signals
    read_off = describing_function(bare, period=120.0, method="least-squares")
    np.testing.assert_allclose(read_off.pilot, describing_function(clean_run).pilot, rtol=1e-9)
    with pytest.raises(ValueError, match=re.escape("cannot read the forcing's lines off")):
        describing_function(bare.slice_samples(0, 6000), period=120.0, method="least-squares")
    tiny = clean_run.slice_samples(0, 200)  # 2 s: lines 1/120 Hz apart cannot be told apart
    with pytest.raises(ValueError, match=r"stretch \(2 s\) is too short"):
        describing_function(tiny, method="least-squares")
