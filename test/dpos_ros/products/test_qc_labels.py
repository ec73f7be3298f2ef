"""The QC figure's log axes (products.qc._plain_log_labels): matplotlib's labels in plain text
(no mathtext parse per figure), the minor ticks kept where they carry labels."""

from __future__ import annotations

import numpy as np

from dpos_ros.products.qc import _plain_log_labels, _plain_power


def test_mathtext_powers_become_plain_text() -> None:
    assert _plain_power(r"$\mathdefault{10^{-4}}$") == "10⁻⁴"
    assert _plain_power(r"$\mathdefault{10^{0}}$") == "10⁰"
    assert _plain_power(r"$\mathdefault{2\times10^{-3}}$") == "2×10⁻³"
    assert _plain_power(r"$\mathdefault{10^{\minus12}}$") == "10⁻¹²"
    assert _plain_power("0.5") == "0.5" and _plain_power("") == ""


def test_log_axes_labels_and_minor_ticks() -> None:
    from matplotlib.figure import Figure

    fig = Figure()
    wide, narrow = fig.subplots(2, 1)
    wide.semilogy([0, 1], [1e-5, 1e2])
    narrow.semilogy([0, 1], [4e-3, 7e-3])
    for ax in (wide, narrow):
        _plain_log_labels(ax)
    fig.canvas.draw()
    labels = [t.get_text() for t in wide.get_yticklabels()]
    assert "10⁻²" in labels and not any("$" in s for s in labels)
    assert len(wide.yaxis.get_minorticklocs()) == 0  # > 1 decade: minor ticks unlabelled, left out
    minor = [t.get_text() for t in narrow.yaxis.get_minorticklabels()]
    assert np.size(narrow.yaxis.get_minorticklocs()) > 0 and "6×10⁻³" in minor
