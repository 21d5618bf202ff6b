"""Shared figure style and deterministic, atomic saving (byte-identical PNG, SVG and PDF)."""
