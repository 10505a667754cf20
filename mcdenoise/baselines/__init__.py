"""Peer denoisers mcdenoise compares against (OIDN)."""
