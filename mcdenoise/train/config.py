"""Training configuration: a dataclass, loadable from TOML, overridable by ``key=value`` flags.

A run folder always holds the *resolved* configuration (``config.json``: every field, after the
file and the overrides were applied), so a run can be repeated or resumed from the folder alone.

Example::

    cfg = load_config("train.toml", overrides={"steps": "200", "lr": "1e-3"})
    cfg.to_json()

Fields are model-agnostic except ``model`` (which model to train, e.g. ``kalantari-xbf``) and
``hidden`` (the model's hidden layer sizes); a model reads only the fields it needs. A new
model starts from its own defaults where :data:`MODEL_DEFAULTS` has them (``kpcn``: the recipe
of the shipped weights), then the file, then the overrides.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_type_hints

from mcdenoise.errors import InputError
from mcdenoise.losses import LOSSES as LOSS_FUNCTIONS
from mcdenoise.modelfile import MAX_WIDTH
from mcdenoise.models.kpcn_temporal import MAX_WINDOW, MIXER_INPUTS

#: Training losses a config may name (``""``: the model's default, see :data:`DEFAULT_LOSS`):
#: those of :mod:`mcdenoise.losses`, and ``log-relmse``
#: (:func:`mcdenoise.losses.crop_log_relmse`, computed per crop by the trainers).
LOSSES = ("log-relmse", *LOSS_FUNCTIONS)
#: Default loss per model family (prefix of the model name).
DEFAULT_LOSS = {"kalantari": "log-relmse", "kpcn": "smape"}
#: Defaults of a new model that differ from the field defaults (a file or flag value wins over
#: them). ``kpcn``: the first command of the recipe of the shipped weights
#: (``data/recipes/kpcn.md``: 5×5 kernels, 16000 steps, lr 1e-3 warmed up over 200 steps);
#: its other settings are the field defaults. A run from a ``base`` model (continued training,
#: a new encoder) keeps the field defaults: its architecture is the base's.
MODEL_DEFAULTS: dict[str, dict[str, Any]] = {
    "kpcn": {
        "kernel": 5,
        "margin": 8,
        "steps": 16000,
        "epoch_steps": 1000,
        "lr": 1e-3,
        "warmup": 200,
    },
}
#: Mixed-precision modes (``amp``); autocast is only used on CUDA devices.
AMP_MODES = ("off", "bf16", "fp16")


@dataclass
class TrainConfig:
    """Everything a training run needs.

    Attributes:
        model: model name (``kalantari-xbf``, ``kalantari-nlm``, ``kpcn``).
        data: folder of a data set made by ``mcdenoise render`` (``<id>.exr`` with parts
            ``spp<n>`` and ``ref/<id>.exr``).
        levels: spp levels (parts) to train on; empty = every level in the files.
        val_fraction: share of *images* held out for validation (split by image, seeded).
        max_images: use at most this many images (0 = all), chosen by the seeded split.
        patch: edge of the square training patch whose loss is computed (pixels).
        margin: context around the patch (the filter footprint), pixels on each side.
        batch: patches per step.
        steps: optimisation steps in total.
        epoch_steps: steps between validations (one "epoch" here: the data set is sampled, not
            iterated).
        lr: peak Adam learning rate; warmed up linearly over ``warmup`` steps, then cosine
            decayed to ``lr * lr_final`` at ``steps``.
        warmup: warm-up steps.
        lr_final: final learning rate as a fraction of ``lr``.
        weight_decay: Adam(W) weight decay.
        importance: share of patches drawn proportionally to the noisy input's error (the rest
            uniformly); informative patches (edges, noise) are seen more often.
        seed: seed of the split, the patch sampler and the model initialisation.
        deterministic: ``torch.use_deterministic_algorithms(True)`` (CPU results are then
            reproducible bit for bit for a given thread count).
        threads: torch intra-op threads (0 = leave torch's default).
        hidden: hidden layer sizes of the model's MLP.
        kernel: filter window edge (odd; the cross-bilateral kernel, the NLM search window or
            the kpcn kernel); 0 = the filter's default (21; a kpcn run from ``base``: the
            base's). A new kpcn model defaults to 5 (:data:`MODEL_DEFAULTS`).
        passes: cross-bilateral passes (1 or 2; the second measures colour distances on the
            first pass's result and has its own learned spatial and colour bandwidths).
        loss: ``relmse`` (mean over the batch's pixels), ``log-relmse`` (mean over crops of
            ``log(relMSE of the crop)``: every crop counts alike whatever its error level, as
            in a geometric mean over images; plain relMSE is dominated by the noisiest crops),
            ``smape``, ``smape+relmse`` (their sum), ``l1`` or ``asymmetric`` (Vogels 2018,
            slope ``asym_slope`` on SMAPE); see :mod:`mcdenoise.losses`. Empty: the model's
            default (Kalantari: log-relmse, KPCN: smape); the resolved config holds the value
            used.
        asym_slope: λ of the asymmetric loss (1 = plain SMAPE; > 1 penalises results on the
            far side of the reference from the noisy input, keeping more detail).
        channels: KPCN U-Net widths per level (full, 1/2, 1/4, ...; at least 2 levels).
        scales: KPCN kernel scales (1 = full resolution only; 3 = full, 1/2, 1/4 with the
            learned scale compositor).
        encoder: KPCN input module: ``source-aware`` (one small encoder per input source in
            front of the shared trunk, Vogels 2018) or ``shared`` (one input layer on the union
            of the buffers, missing ones zero-filled: the ablation).
        albedo_kernels: KPCN: also predict kernels that filter the remodulation albedo (where
            it is noisy: sub-pixel texture, depth of field); a base without them, continued
            with ``albedo_kernels = true``, gets a new head that starts near a delta.
        sources: KPCN input sources trained (``full``, ``basic``); each training crop is shown
            to the network as one of them, chosen at random.
        augment: random flips, 90° rotations and colour-channel permutations of the crops.
        exposure: KPCN: scale each crop's colour and reference by ``2^u``, ``u`` uniform in
            ``[-exposure, exposure]`` stops (the variance by the square); 0 = off.
        normalize_exposure: KPCN: scale each training image as ``kpcn -p exposure=auto``
            does at inference (:func:`mcdenoise.prep.kpcn.exposure_scale`; the reference too).
        prefilter: KPCN: how the ``basic`` crops' albedo and normal are prefiltered, as
            ``kpcn -p prefilter=`` does at inference on an input without feature variances
            (``auto`` or ``all``: the variance estimated from the feature; ``off``: as
            rendered). ``all`` also prefilters the ``full`` crops' features with their
            variances; ``adaptive`` and ``learned`` prepare both sources exactly as
            ``kpcn -p prefilter=adaptive`` (the default) and ``learned`` do at inference
            (``learned``: the albedo and normal by the shipped auxnet).
        amp: mixed precision on CUDA (``off``, ``bf16``, ``fp16``): the convolutions run in
            the low precision, the kernel softmax, kernel application and loss in float32.
        finetune_encoder: train only the encoder of this source against a frozen trunk
            (Vogels 2018); needs ``base``.
        finetune_keep: with ``finetune_encoder``, start from the base's own encoder (and
            normalisation statistics) of that source instead of a fresh one: e.g. adapt the
            ``basic`` encoder to prefiltered features while every other weight, and so the
            ``full`` source's results, stay exactly the base's.
        base: run folder or model file to start from: with ``finetune_encoder``, its trunk
            is kept frozen; alone (kpcn), the whole model is trained further with this
            run's schedule (its architecture must match the config's).
        guides: guide features the model uses (and will require at inference); images of
            the data set without one of them are skipped and reported.
        regional: Kalantari models: also the regional feature means (63×63 windows; see
            :mod:`mcdenoise.models.features`).
        checkpoints_kept: how many checkpoints to keep in ``checkpoints/`` (the newest ones).
        device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``.
        window: kpcn-temporal: frames per window (odd for ``offline``).
        temporal_mode: kpcn-temporal: ``offline`` (past and future frames) or ``causal``.
        temporal_weight: kpcn-temporal: weight of the temporal SMAPE term
            (:func:`mcdenoise.losses.temporal_smape`) added to ``loss``.
        trunk: kpcn-temporal: ``frozen`` (train the temporal module only, the paper's first
            stage) or ``train`` (fine-tune everything).
        temporal_inputs: kpcn-temporal: the temporal module's inputs (card ``inputs``: 1, the
            trunk's features and masks; 2, also the noise-normalised difference to frame t
            and the variance ratio).
        recurrent: kpcn-temporal: the previous output, warped to frame t, is one more kernel
            source (trained on three consecutive frames, unrolled).
        temporal_loss: kpcn-temporal: ``warped`` (the previous output and reference warped to
            frame t along the motion, masked where the warp is invalid) or ``same-pixel``
            (frame differences at the same pixel, the first shipped model's).
    """

    model: str = "kalantari-xbf"
    data: str = ""
    levels: list[int] = field(default_factory=list)
    val_fraction: float = 0.15
    max_images: int = 0
    patch: int = 48
    margin: int = 10
    batch: int = 8
    steps: int = 1000
    epoch_steps: int = 100
    lr: float = 3e-3
    warmup: int = 20
    lr_final: float = 0.05
    weight_decay: float = 0.0
    importance: float = 0.5
    seed: int = 0
    deterministic: bool = True
    threads: int = 0
    hidden: list[int] = field(default_factory=lambda: [32])
    kernel: int = 0
    passes: int = 1
    loss: str = ""
    asym_slope: float = 2.0
    channels: list[int] = field(default_factory=lambda: [24, 32, 48, 64])
    scales: int = 3
    encoder: str = "source-aware"
    albedo_kernels: bool = False
    sources: list[str] = field(default_factory=lambda: ["full", "basic"])
    augment: bool = True
    exposure: float = 0.0
    normalize_exposure: bool = False
    prefilter: str = "off"
    amp: str = "off"
    finetune_encoder: str = ""
    finetune_keep: bool = False
    base: str = ""
    guides: list[str] = field(default_factory=lambda: ["albedo", "normal", "depth", "position"])
    regional: bool = False
    checkpoints_kept: int = 3
    device: str = "cpu"
    window: int = 5
    temporal_mode: str = "offline"
    temporal_weight: float = 0.5
    trunk: str = "frozen"
    temporal_inputs: int = 2
    recurrent: bool = False
    temporal_loss: str = "warped"

    def __post_init__(self) -> None:
        if not self.loss:
            family = self.model.split("-")[0]
            self.loss = DEFAULT_LOSS.get(family, "log-relmse")
        checks = [
            (self.patch >= 8, f"patch must be >= 8, got {self.patch}"),
            (self.margin >= 0, f"margin must be >= 0, got {self.margin}"),
            (self.batch >= 1, f"batch must be >= 1, got {self.batch}"),
            (self.steps >= 1, f"steps must be >= 1, got {self.steps}"),
            (self.epoch_steps >= 1, f"epoch_steps must be >= 1, got {self.epoch_steps}"),
            (self.lr > 0, f"lr must be > 0, got {self.lr}"),
            (
                0 <= self.val_fraction < 1,
                f"val_fraction must be in [0, 1), got {self.val_fraction}",
            ),
            (0 <= self.importance <= 1, f"importance must be in [0, 1], got {self.importance}"),
            (0 < self.lr_final <= 1, f"lr_final must be in (0, 1], got {self.lr_final}"),
            (
                all(1 <= h <= MAX_WIDTH for h in self.hidden),
                f"hidden sizes must be in [1, {MAX_WIDTH}] (what a model file may hold), "
                f"got {self.hidden}",
            ),
            (all(v >= 1 for v in self.levels), f"levels must be spp >= 1, got {self.levels}"),
            (self.checkpoints_kept >= 1, "checkpoints_kept must be >= 1"),
            (
                self.kernel == 0 or (self.kernel >= 3 and self.kernel % 2 == 1),
                f"kernel must be 0 (default) or an odd size >= 3, got {self.kernel}",
            ),
            (self.passes in (1, 2), f"passes must be 1 or 2, got {self.passes}"),
            (
                1 <= self.window <= MAX_WINDOW,
                f"window must be in [1, {MAX_WINDOW}], got {self.window}",
            ),
            (
                self.temporal_mode in ("offline", "causal"),
                f"temporal_mode must be offline or causal, got {self.temporal_mode!r}",
            ),
            (
                self.temporal_weight >= 0,
                f"temporal_weight must be >= 0, got {self.temporal_weight}",
            ),
            (
                self.trunk in ("frozen", "train"),
                f"trunk must be frozen or train, got {self.trunk!r}",
            ),
            (
                self.temporal_inputs in MIXER_INPUTS,
                f"temporal_inputs must be one of {sorted(MIXER_INPUTS)}, "
                f"got {self.temporal_inputs}",
            ),
            (
                self.temporal_loss in ("warped", "same-pixel"),
                f"temporal_loss must be warped or same-pixel, got {self.temporal_loss!r}",
            ),
            (self.loss in LOSSES, f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}"),
            (self.asym_slope >= 1, f"asym_slope must be >= 1, got {self.asym_slope}"),
            (
                2 <= len(self.channels) <= 8 and all(1 <= c <= MAX_WIDTH for c in self.channels),
                f"channels needs 2 to 8 levels of 1 to {MAX_WIDTH} channels (what a model file "
                f"may hold), got {self.channels}",
            ),
            (1 <= self.scales <= len(self.channels), "scales must be in [1, len(channels)]"),
            (
                self.encoder in ("source-aware", "shared"),
                f"encoder must be source-aware or shared, got {self.encoder!r}",
            ),
            (self.exposure >= 0, f"exposure must be >= 0 stops, got {self.exposure}"),
            (
                self.prefilter in ("auto", "all", "off", "adaptive", "learned"),
                f"prefilter must be auto, all, off, adaptive or learned, got {self.prefilter!r}",
            ),
            (self.amp in AMP_MODES, f"amp must be one of {', '.join(AMP_MODES)}, got {self.amp!r}"),
            (
                not self.finetune_keep or bool(self.finetune_encoder),
                "finetune_keep needs finetune_encoder (the source whose encoder is kept)",
            ),
            (
                not self.finetune_encoder or bool(self.base),
                "finetune_encoder needs base (the run folder whose trunk is kept)",
            ),
            (
                not self.regional or self.model != "kpcn",
                "regional (the regional feature means) is for kalantari models only",
            ),
            (
                not self.base or self.model in ("kpcn", "kpcn-temporal"),
                f"base (--from) is for kpcn models only, not {self.model}",
            ),
        ]
        for ok, message in checks:
            if not ok:
                raise InputError(message)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True, allow_nan=False) + "\n"


def _coerce(name: str, value: Any, kind: Any) -> Any:
    """Convert a TOML/JSON value or a flag string to the field's type, or raise InputError."""
    text = isinstance(value, str)
    try:
        if kind is bool:
            if isinstance(value, bool):
                return value
            if text and value.lower() in ("1", "true", "yes", "on"):
                return True
            if text and value.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if kind is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError
            return int(value)
        if kind is float:
            if isinstance(value, bool):
                raise ValueError
            return float(value)
        if kind is str:
            if not isinstance(value, str):
                raise ValueError
            return value
        if kind in (list[int], list[str]):
            if text:
                value = [v for v in value.replace(" ", "").split(",") if v]
            if not isinstance(value, list):
                raise ValueError
            item = int if kind == list[int] else str
            return [_coerce(name, v, item) for v in value]
    except (TypeError, ValueError):
        pass
    raise InputError(f"config key {name!r}: cannot use {value!r} (expected {_type_name(kind)})")


def _type_name(kind: Any) -> str:
    if kind == list[int]:
        return "list of integers"
    if kind == list[str]:
        return "list of names"
    return getattr(kind, "__name__", str(kind))


def model_defaults(values: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`MODEL_DEFAULTS` that apply to a config given as ``values``: those of its
    model (default ``kalantari-xbf``) when it trains a new model (no ``base``), else none."""
    if values.get("base"):
        return {}
    model = values.get("model", TrainConfig.model)
    return dict(MODEL_DEFAULTS.get(model, {})) if isinstance(model, str) else {}


def make_config(values: Mapping[str, Any], *, source: str = "config") -> TrainConfig:
    """A :class:`TrainConfig` from a mapping, over the model's defaults
    (:func:`model_defaults`); unknown keys are an :class:`InputError`."""
    hints = get_type_hints(TrainConfig)
    names = [f.name for f in dataclasses.fields(TrainConfig)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InputError(
            f"{source}: unknown key(s) {', '.join(unknown)}; known: {', '.join(names)}"
        )
    merged = {**model_defaults(values), **values}
    return TrainConfig(**{k: _coerce(k, v, hints[k]) for k, v in merged.items()})


def load_config(
    path: str | os.PathLike[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> TrainConfig:
    """Defaults (the model's, see :func:`model_defaults`), then the TOML (or JSON) file
    ``path``, then ``overrides`` (flag strings ok).

    Raises:
        InputError: unreadable file, TOML syntax error, unknown key or bad value.
    """
    values: dict[str, Any] = {}
    source = "config"
    if path is not None:
        p = Path(path)
        source = str(p)
        if p.exists() and not p.is_file():  # a named pipe would block the read
            raise InputError(f"{p}: not a regular file; refused")
        try:
            text = p.read_text()
        except OSError as err:
            raise InputError(f"{p}: cannot read config ({err.strerror or err})") from None
        try:
            values = json.loads(text) if p.suffix == ".json" else tomllib.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as err:
            raise InputError(f"{p}: {err}") from None
        if "train" in values and isinstance(values["train"], dict):
            values = dict(values["train"])
    merged = {**values, **dict(overrides or {})}
    return make_config(merged, source=source)
