"""Shared figure style and deterministic, atomic saving (byte-identical PNG, SVG and PDF), and the figures of
the commands and the studies, one module per topic (``*_plots``), each drawn from the arrays and dicts the
layers above compute: this layer imports none of them."""
