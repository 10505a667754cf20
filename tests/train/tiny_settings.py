"""The tiny Kalantari training settings shared by the loop and distributed tests (seconds per
run on the ``tiny_dataset`` fixture)."""

TINY_KALANTARI = {
    "model": "kalantari-xbf",
    "kernel": 5,
    "patch": 16,
    "margin": 2,
    "batch": 4,
    "steps": 12,
    "epoch_steps": 6,
    "lr": 1e-2,
    "warmup": 2,
    "val_fraction": 0.25,
    "hidden": "8",
    "threads": 1,
}
