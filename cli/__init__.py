"""click wiring for the mcdenoise command (installed as the package mcdenoise_cli)."""
