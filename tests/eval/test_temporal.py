"""Tests for mcdenoise/eval/temporal_metrics.py: temporal relMSE, Noisebase's tPSNR/tRMAE, warm-up."""

from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.eval import temporal_metrics as T
from mcdenoise.eval.metrics import MetricUnavailable, relmse
from mcdenoise.eval.noisebase import noisebase_uint8

H, W = 8, 10


def reference_sequence(frames: int = 6, seed: int = 0) -> np.ndarray:
    """A textured static scene ``(T, 3, H, W)`` with a bright square moving 1 px per frame."""
    rng = np.random.default_rng(seed)
    base = rng.gamma(2.0, 0.3, size=(3, H, W))
    seq = np.repeat(base[None], frames, axis=0)
    for t in range(frames):
        seq[t, :, 2:5, t % W : t % W + 3] += 1.5
    return seq


# --- literal port of Noisebase (github.com/balintio/noisebase @ 63056ed) -----------------------
# noisebase/data.py: ACES; noisebase/loaders/torch/test_sample_v1.py: Sequence.save;
# noisebase/scripts/nb_compute_metrics.py: np_to_torch, mse, psnr, rmae, TemporalMetricAdapter.
# Kept as in the source (HWC numpy for the tonemap, NCHW float32 torch for the metrics).


def nb_aces(x, gamma_correct=True, gamma=2.2):
    ACESInputMat = np.array(
        [[0.59719, 0.35458, 0.04823], [0.07600, 0.90834, 0.01566], [0.02840, 0.13383, 0.83777]]
    )
    ACESOutputMat = np.array(
        [
            [1.60475, -0.53108, -0.07367],
            [-0.10208, 1.10813, -0.00605],
            [-0.00327, -0.07276, 1.07602],
        ]
    )
    x = np.einsum("ji, hwi -> hwj", ACESInputMat, x)
    a = x * (x + 0.0245786) - 0.000090537
    b = x * (0.983729 * x + 0.4329510) + 0.238081
    x = a / b
    x = np.einsum("ji, hwi -> hwj", ACESOutputMat, x)
    if gamma_correct:
        return np.power(np.clip(x, 0.0, 1.0), 1.0 / gamma)
    return x


def nb_save(image_chw):  # Sequence.save, without the file: the uint8 HWC frame it writes
    image = np.transpose(image_chw, (1, 2, 0))
    return (nb_aces(image) * 255).astype(np.uint8)


def nb_np_to_torch(hwc):  # reshuffle_dims(HWC -> NCHW), float32 / 255
    return torch.tensor(hwc).permute(2, 0, 1)[None].to(torch.float32) / 255


def nb_mse(test, reference):
    return float(torch.mean((test - reference) ** 2))


def nb_psnr(test, reference):
    return float(10 * np.log10(1 / nb_mse(test, reference)))


def nb_rmae(test, reference):
    return float(torch.mean(torch.abs(test - reference) / (torch.abs(reference) + 0.01))) / 3


class NbTemporalMetricAdapter:
    def __init__(self, spatial_metric):
        self.spatial_metric = spatial_metric
        self.prev_test = None
        self.prev_ref = None
        self.N = 0
        self.sum = 0.0

    def feed(self, test, reference):
        if self.prev_test is not None:
            self.sum += self.spatial_metric(test - self.prev_test, reference - self.prev_ref)
            self.N += 1
        self.prev_test = test
        self.prev_ref = reference

    def compute(self):
        return self.sum / self.N


def noisebase_numbers(outputs, references, warmup):
    tpsnr, trmae = NbTemporalMetricAdapter(nb_psnr), NbTemporalMetricAdapter(nb_rmae)
    for i in range(warmup, len(outputs)):  # nb_compute_metrics reads range(warmup, frames)
        test = nb_np_to_torch(nb_save(outputs[i]))
        reference = nb_np_to_torch(nb_save(references[i]))
        tpsnr.feed(test, reference)
        trmae.feed(test, reference)
    return tpsnr.compute(), trmae.compute()


# --- Noisebase pins ----------------------------------------------------------------------------


def test_noisebase_display_pinned_by_hand():
    # grey 1.0: the input matrix keeps it (rows sum to 1); (1.0245786 − 0.000090537) /
    # (0.983729 + 0.4329510 + 0.238081) = 0.619115; the output matrix's rows sum to 1, 1,
    # 0.99999; 0.619115 ** (1 / 2.2) * 255 = 205.06 (B: 205.06) -> truncated to 205.
    # Black: (−0.000090537 / 0.238081) < 0 is clipped to 0. Huge values saturate at 255.
    img = np.zeros((3, 1, 3))
    img[:, 0, 1] = 1.0
    img[:, 0, 2] = 1e6
    u8 = noisebase_uint8(img)
    assert u8.dtype == np.uint8
    assert u8[:, 0, 0].tolist() == [0, 0, 0]
    assert u8[:, 0, 1].tolist() == [205, 205, 205]
    assert u8[:, 0, 2].tolist() == [255, 255, 255]


def test_noisebase_tonemap_equals_the_port_exactly():
    rng = np.random.default_rng(3)
    img = rng.gamma(0.7, 1.0, size=(3, 16, 16))
    img[0, 0, :4] = [0.0, -0.2, 30.0, 1e-4]
    assert np.array_equal(noisebase_uint8(img), np.moveaxis(nb_save(img), -1, 0))


def test_noisebase_pair_values_by_hand():
    # one pixel, 8-bit values: reference 100,100,100 -> 110,100,90, output stays 100.
    # Δo − Δr = (−10, 0, 10) / 255: MSE = 200 / 3 / 255²; tPSNR = 10·log10(255² · 3 / 200)
    # = 29.8917 dB. tRMAE = mean((10/255) / (10/255 + 0.01), 0, same) / 3
    # = (2 · 0.796813 / 3) / 3 = 0.177069.
    px = lambda *v: np.array(v, dtype=np.float64).reshape(3, 1, 1) / 255  # noqa: E731
    o0, o1, r0, r1 = px(100, 100, 100), px(100, 100, 100), px(100, 100, 100), px(110, 100, 90)
    assert T.TEMPORAL_METRICS["tpsnr"].pair(o0, o1, r0, r1) == pytest.approx(29.891716, abs=1e-6)
    assert T.TEMPORAL_METRICS["trmae"].pair(o0, o1, r0, r1) == pytest.approx(0.1770695, abs=1e-7)
    assert T.TEMPORAL_METRICS["tpsnr"].pair(o0, o0, r0, r0) == math.inf  # Noisebase: 1 / 0


@pytest.mark.parametrize("warmup", [0, 2])
def test_tpsnr_trmae_equal_noisebase_port(warmup):
    ref = reference_sequence(7)
    rng = np.random.default_rng(5)
    out = ref * (1 + 0.3 * rng.standard_normal(ref.shape)) + 0.05
    expect_psnr, expect_rmae = noisebase_numbers(out, ref, warmup)
    assert T.tpsnr(out, ref, warmup=warmup) == pytest.approx(expect_psnr, rel=1e-5)
    assert T.trmae(out, ref, warmup=warmup) == pytest.approx(expect_rmae, rel=1e-5)
    # the evaluator's headline values are Noisebase's numbers for the same warm-up
    s = T.sequence_metrics(out, ref, ["tpsnr", "trmae"], warmup=warmup)
    assert s.values["tpsnr"] == pytest.approx(expect_psnr, rel=1e-5)
    assert s.values["trmae"] == pytest.approx(expect_rmae, rel=1e-5)


# --- temporal relMSE ---------------------------------------------------------------------------


def test_temporal_relmse_literal_definition():
    ref = reference_sequence(5)
    rng = np.random.default_rng(1)
    out = ref + 0.1 * rng.standard_normal(ref.shape)
    terms = [
        np.mean(((out[t] - out[t - 1]) - (ref[t] - ref[t - 1])) ** 2 / (ref[t] ** 2 + 0.01))
        for t in range(1, 5)
    ]
    assert T.temporal_relmse(out, ref) == pytest.approx(np.mean(terms), rel=1e-12)
    # the relMSE of the frame difference, normalised by the current reference frame
    assert terms[0] != pytest.approx(relmse(out[1] - out[0], ref[1] - ref[0]))


def test_static_sequence_denoised_identically_has_zero_temporal_error():
    ref = np.repeat(reference_sequence(1), 5, axis=0)
    out = np.repeat((ref[0] * 0.9 + 0.01)[None], 5, axis=0)  # biased, but the same every frame
    s = T.sequence_metrics(out, ref, warmup=1)
    for group in (s.values, s.warmup_values, s.all_values):
        assert group["trelmse"] == 0.0
        assert group["trmae"] == 0.0
        assert group["tpsnr"] == math.inf
    assert s.values["relmse"] > 0  # the bias is still seen per frame
    assert T.temporal_relmse(out, ref) == 0.0


def test_flicker_costs_more_than_a_stable_bias():
    ref = reference_sequence(8)  # a square moves over a still background
    rng = np.random.default_rng(2)
    flicker = ref * (1 + 0.1 * rng.standard_normal(ref.shape))  # independent noise per frame
    biased = ref * 1.1  # 10 % too bright in every frame: stable
    names = ["relmse", "trelmse", "tpsnr", "trmae"]
    f = T.sequence_metrics(flicker, ref, names, warmup=0).values
    b = T.sequence_metrics(biased, ref, names, warmup=0).values
    assert f["relmse"] == pytest.approx(b["relmse"], rel=0.2)  # per frame: about as wrong
    assert f["trelmse"] > 3 * b["trelmse"]  # the bias only scales the square's real motion
    assert f["tpsnr"] < b["tpsnr"] - 10
    assert f["trmae"] > 10 * b["trmae"]


# --- warm-up, undefined values, failures, shapes -------------------------------------------------


def test_warmup_frames_are_reported_apart():
    ref = reference_sequence(6)
    rng = np.random.default_rng(4)
    out = ref + np.linspace(0.5, 0.0, 6)[:, None, None, None] * rng.standard_normal(ref.shape)
    s = T.sequence_metrics(out, ref, ["relmse", "trelmse"], warmup=2)
    per_frame = [relmse(out[t], ref[t]) for t in range(6)]
    pairs = [f.values["trelmse"] for f in s.frames]
    assert pairs[0] is None and [f.warmup for f in s.frames] == [True, True] + [False] * 4
    assert s.values["relmse"] == pytest.approx(np.mean(per_frame[2:]))
    assert s.warmup_values["relmse"] == pytest.approx(np.mean(per_frame[:2]))
    assert s.all_values["relmse"] == pytest.approx(np.mean(per_frame))
    assert s.values["trelmse"] == pytest.approx(np.mean(pairs[3:]))  # both frames past warm-up
    assert s.warmup_values["trelmse"] == pytest.approx(np.mean(pairs[1:3]))
    assert s.all_values["trelmse"] == pytest.approx(T.temporal_relmse(out, ref))
    assert s.values["relmse"] < s.warmup_values["relmse"]  # the noise decays in this sequence


def test_one_frame_sequence_temporal_metrics_are_undefined_not_zero():
    ref = reference_sequence(1)
    s = T.sequence_metrics(ref * 1.1, ref, warmup=0)
    for m in T.TEMPORAL_METRICS:
        assert s.values[m] is None and s.all_values[m] is None
        assert "1 frame has no frame pair" in s.unavailable[m]
    assert s.values["relmse"] == pytest.approx(relmse(ref[0] * 1.1, ref[0]))
    with pytest.raises(MetricUnavailable, match="needs 2 frames"):
        T.temporal_relmse(ref, ref)
    with pytest.raises(MetricUnavailable, match="needs 2 frames"):
        T.tpsnr(reference_sequence(3), reference_sequence(3), warmup=2)
    # default warm-up 2: a 2-frame sequence is all warm-up; its numbers are in the warm-up group
    two = reference_sequence(2)
    s = T.sequence_metrics(two * 1.1, two)
    assert s.values["relmse"] is None and "every frame is warm-up" in s.unavailable["relmse"]
    assert (
        s.values["trelmse"] is None and "no frame pair past the warm-up" in s.unavailable["trelmse"]
    )
    assert s.warmup_values["relmse"] is not None and s.warmup_values["trelmse"] is not None


def test_a_nan_frame_fails_the_sequence():
    ref = reference_sequence(4)
    out = ref.copy()
    out[2, 0, 1, 1] = np.nan
    s = T.sequence_metrics(out, ref, ["relmse", "trelmse"], warmup=0)
    assert s.failed and s.bad_pixels == 1 and "1 of 4 frames failed" in s.reason
    assert s.values == {"relmse": None, "trelmse": None}
    assert s.frames[2].failed and s.frames[3].values["trelmse"] is None
    assert "previous frame failed" in s.frames[3].unavailable["trelmse"]


def test_shapes_are_checked_and_inputs_of_both_layouts_agree():
    ref = reference_sequence(3)
    out = ref * 1.1
    as_list = T.sequence_metrics(list(out), list(torch.from_numpy(ref)), ["relmse", "trelmse"])
    as_array = T.sequence_metrics(out, ref, ["relmse", "trelmse"])
    assert as_list.all_values == as_array.all_values
    with pytest.raises(InputError, match="2 output frames but 3 reference frames"):
        T.sequence_metrics(out[:2], ref)
    ev = T.SequenceEvaluator(["relmse"], warmup=0)
    ev.feed(out[0], ref[0], frame="frame_0000")
    with pytest.raises(InputError, match="frames of a sequence must have one size"):
        ev.feed(np.ones((3, 4, 4)), np.ones((3, 4, 4)), frame="frame_0001")
    with pytest.raises(InputError, match="sizes must match"):
        ev.feed(np.ones((3, H, W)), np.ones((3, H, W + 1)))
    with pytest.raises(InputError, match="warm-up"):
        T.SequenceEvaluator(warmup=-1)


def test_metric_names():
    assert T.resolve_sequence_metrics(None)[-3:] == ["trelmse", "tpsnr", "trmae"]
    assert T.resolve_sequence_metrics(["trmae", "bias"]) == [
        "bias",
        "bias_r",
        "bias_g",
        "bias_b",
        "trmae",
    ]
    with pytest.raises(InputError, match="temporal \\(sequences\\): trelmse"):
        T.resolve_sequence_metrics(["tflip"])
    assert T.metric_spec("tpsnr").describe()["temporal"] is True
    assert T.metric_spec("relmse").label == "relMSE"


def test_docstring_examples():
    failed, attempted = doctest.testmod(T, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0
