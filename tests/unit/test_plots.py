"""The paper-style figures read right: units fitted to the values, every line in a legend, the side
named in every title. Checked on a synthetic log with known values, by capturing the figures."""

import json

import matplotlib
import matplotlib.figure
import matplotlib.pyplot
import numpy as np
import pytest

from teleop.app import plots


@pytest.mark.parametrize("values, unit, scale, shown", [
    ([1.25e-7], "rad", 1e9, "nrad"),    # 0.000125 mrad is 125 nrad
    ([2.0e-4, -3e-4], "rad", 1e6, "µrad"),
    ([0.03], "m/s", 1e3, "mm/s"),       # a rate takes the prefix on its numerator
    ([4.2], "N", 1.0, "N"),
    ([0.0, 0.0], "m", 1.0, "m"),        # nothing to scale
    ([37.0], "%", 1.0, "%"),
    ([1e-19], "m", 1e15, "fm"),         # below every prefix: the smallest one
])
def test_auto_unit_puts_the_peak_between_1_and_1000(values, unit, scale, shown):
    assert plots.auto_unit(np.array(values), unit) == (scale, shown)
    peak = np.max(np.abs(values)) * scale
    assert peak == 0.0 or peak >= 1.0 or shown == "fm"
    assert peak < 1000.0


def _synthetic_log(path, master="cobot"):
    n = 50
    t = np.linspace(0.0, 0.49, n)
    log = {"t": t, "tick_us": np.full(n, 20.0),
           "m_sphere_deviation_m": 3e-6 * np.sin(t), "m_normal_angle_error_rad": 1.25e-7 * np.cos(t),
           "m_normal_force_N": 35.0 + t, "m_normal_force_expected_N": 35.0 + 0.9 * t,
           "slave_track_m": 1e-5 * t, "slave_depth_err_m": 5e-8 * t, "slave_dir_err_rad": 2e-4 * t,
           "slave_contact_N": 4.0 + t}
    summary = {"scenario": "synthetic", "master": master, "integrator": "parametric"}
    np.savez(path, **log, summary=json.dumps(summary))


def _figures(monkeypatch, tmp_path, master="cobot"):
    saved = []
    real = matplotlib.figure.Figure.savefig

    def keep(fig, path, *a, **k):
        saved.append((str(path), fig))
        return real(fig, path, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    monkeypatch.setattr(matplotlib.pyplot, "close", lambda *a: None)  # keep them to read back
    _synthetic_log(tmp_path / "log.npz", master)
    plots.plot_log(tmp_path / "log.npz", tmp_path)
    return {p.rsplit("/", 1)[1]: f for p, f in saved}


def test_every_line_is_in_a_legend_and_every_title_names_its_side(monkeypatch, tmp_path):
    figs = _figures(monkeypatch, tmp_path)
    assert set(figs) == {"figure10.png", "incision.png", "tick_time.png"}
    for name, side in (("figure10.png", "MASTER side"), ("incision.png", "SLAVE side"),
                       ("tick_time.png", "BOTH sides")):
        fig = figs[name]
        assert side in fig._suptitle.get_text(), name
        legend_labels = {t.get_text() for lg in fig.legends for t in lg.get_texts()}
        for ax in fig.axes:
            for line in ax.get_lines():
                assert line.get_label() in legend_labels, (name, line.get_label())
    assert "encoders" in figs["figure10.png"]._suptitle.get_text()  # device data on the cobot


def test_units_fit_the_values(monkeypatch, tmp_path):
    figs = _figures(monkeypatch, tmp_path)
    ylabels = [ax.get_ylabel() for ax in figs["figure10.png"].axes]
    assert "[µm]" in ylabels[0] and "[nrad]" in ylabels[1] and "[N]" in ylabels[2]
    angle = figs["figure10.png"].axes[1].get_lines()[0].get_ydata()
    assert np.max(np.abs(angle)) == pytest.approx(125.0)  # 1.25e-7 rad drawn as 125 nrad
    s = [ax.get_ylabel() for ax in figs["incision.png"].axes]
    assert "[µm]" in s[0] and "[nm]" in s[1] and "[µrad]" in s[2]


def test_the_ideal_master_says_it_plots_the_exact_tool(monkeypatch, tmp_path):
    figs = _figures(monkeypatch, tmp_path, master="ideal")
    assert "ideal master" in figs["figure10.png"]._suptitle.get_text()
