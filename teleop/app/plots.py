"""Figure 8- and Figure 10-style plots of a run log (matplotlib, headless Agg backend).

Every figure names its side in its title (the master side's tool as the encoders measure it, or
the slave side's), every line is in a legend, and each panel's unit is chosen from its values
(µm or nm, mrad or µrad, ...) so the numbers read as the paper's do.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

# (series key in the log, quantity, SI unit)
PANELS = {
    "rolling_disk": [
        ("m_height_error_m", "A) height error", "m"),
        ("m_upright_error_rad", "B) upright error", "rad"),
        ("m_rolling_velocity_m_s", "C) rolling velocity V", "m/s"),
        ("m_rolling_error_pct", "D) rolling error", "%"),
    ],
    "sphere": [
        ("m_sphere_deviation_m", "A) deviation from sphere", "m"),
        ("m_normal_angle_error_rad", "B) normal angle error", "rad"),
        ("m_normal_force_N", "C) normal force", "N"),
    ],
    "scalpel": [
        ("m_depth_error_m", "A) blade depth error", "m"),
        ("m_blade_tilt_rad", "B) blade tilt", "rad"),
        ("m_sideslip_m_per_s", "C) sideways slip", "m/s"),
        ("m_cut_speed_m_per_s", "D) cutting speed", "m/s"),
    ],
}
FIGURE_NAME = {"rolling_disk": "figure8", "sphere": "figure10", "scalpel": "scalpel"}
# the slave's side of a run with a slave (patient frame); the RCM panel only where a trocar is
SLAVE_PANELS = [
    ("slave_track_m", "A) tip tracking error", "m"),
    ("slave_depth_err_m", "B) cut depth error", "m"),
    ("slave_dir_err_rad", "C) cut direction error", "rad"),
    ("slave_contact_N", "D) tissue contact force", "N"),
    ("slave_rcm_m", "E) trocar (RCM) error", "m"),
]
#: SI prefixes tried, largest first: (factor to multiply by, prefix)
PREFIXES = ((1.0, ""), (1e3, "m"), (1e6, "µ"), (1e9, "n"), (1e12, "p"), (1e15, "f"))


def auto_unit(values, unit: str) -> tuple[float, str]:
    """(scale, unit label) so that ``values * scale`` has its largest magnitude in [1, 1000): the
    SI prefix that fits, e.g. 1.25e-7 rad -> (1e6, "µrad"); "%" and all-zero series stay as
    they are. A rate unit ("m/s") takes the prefix on its numerator ("mm/s")."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    peak = float(np.max(np.abs(v))) if v.size else 0.0
    if unit == "%" or peak == 0.0:
        return 1.0, unit
    for scale, prefix in PREFIXES:
        if peak * scale >= 1.0:
            return scale, prefix + unit
    scale, prefix = PREFIXES[-1]
    return scale, prefix + unit


#: below this many SI units a series is round-off (an exact constraint), and says so
ROUND_OFF = 1e-12


def _master_title(summary: dict) -> str:
    where = ("by the cobot's encoders (device data)" if summary["master"] == "cobot"
             else "on the ideal master (the reference tool: exact up to round-off)")
    return (f"{summary['scenario']}: MASTER side\nthe tool as measured {where}; "
            f"integrator {summary['integrator']}")


def _panel(ax, t, y, label: str, unit: str, line_label: str):
    scale, shown = auto_unit(y, unit)
    ax.plot(t, y * scale, lw=0.8, label=line_label)
    small = unit != "%" and 0.0 < np.nanmax(np.abs(y)) < ROUND_OFF
    ax.set_ylabel(f"{label} [{shown}]" + ("\n(round-off)" if small else ""), fontsize=8)
    ax.grid(alpha=0.3)
    return scale


def _finish(fig, axes, title: str) -> None:
    """Title (left) and, on the right, a legend of every line of the panels; panels with lines
    of their own beyond the first also get their own legend."""
    handles, labels = [], []
    for ax in axes:
        for line in ax.get_lines():
            if line.get_label() not in labels:
                handles.append(line)
                labels.append(line.get_label())
        if len(ax.get_lines()) > 1:
            ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(title, fontsize=9, x=0.02, ha="left")
    fig.legend(handles, labels, loc="upper right", fontsize=7, frameon=False)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.93))


def plot_log(log_path, out_dir) -> list[Path]:
    """Write the paper-style figures of a run's log.npz into ``out_dir``; returns the PNG paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with np.load(log_path) as z:
        log = {k: z[k] for k in z.files}
    summary = json.loads(str(log.pop("summary")))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    kind = next((k for k, panels in PANELS.items() if panels[0][0] in log), None)
    measured = "measured (device)" if summary["master"] == "cobot" else "reference tool (ideal master)"
    written = []
    if kind is not None:
        panels = PANELS[kind]
        fig, axes = plt.subplots(len(panels), 1, figsize=(7.5, 2.0 * len(panels)), sharex=True)
        t = log["t"]
        for ax, (key, label, unit) in zip(axes, panels):
            scale = _panel(ax, t, log[key], label, unit, measured)
            if key == "m_normal_force_N" and "m_normal_force_expected_N" in log:
                ax.plot(t, log["m_normal_force_expected_N"] * scale, "--", lw=0.8, label="expected: push − m v²/r")
        axes[-1].set_xlabel("time [s]")
        _finish(fig, axes, _master_title(summary))
        path = out_dir / f"{FIGURE_NAME[kind]}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    if "slave_contact_N" in log:
        written.append(_plot_slave(plt, log, summary, out_dir / "incision.png"))
    if "tdpa_W_master_J" in log:
        written.append(plot_passivity(plt, log, f"{summary['scenario']}: passivity guard", out_dir / "passivity.png"))
    fig, ax = plt.subplots(figsize=(7.5, 2.4))
    ax.plot(log["t"], log["tick_us"], lw=0.5, label="whole bilateral tick (master and slave)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("CPU time per tick [µs]")
    ax.set_yscale("log")
    _finish(fig, [ax], f"{summary['scenario']}: BOTH sides\nCPU time of each tick ({summary['master']} master)")
    path = out_dir / "tick_time.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)
    return written


def _plot_slave(plt, log, summary, path: Path) -> Path:
    """The slave's panels of ``SLAVE_PANELS`` against time: tracking, depth, direction, the tissue
    force that goes back to the operator, and the trocar error when the scene has one."""
    panels = [p for p in SLAVE_PANELS if p[0] in log]  # the RCM series only where there is a trocar
    fig, axes = plt.subplots(len(panels), 1, figsize=(7.5, 2.0 * len(panels)), sharex=True)
    t = log["t"][: len(log[panels[0][0]])]
    for ax, (key, label, unit) in zip(axes, panels):
        _panel(ax, t, log[key], label, unit, "slave arm's tool (patient frame)")
    axes[-1].set_xlabel("time [s]")
    _finish(fig, axes, f"{summary['scenario']}: SLAVE side\nthe arm's tool in the tissue ({summary['master']} master)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_passivity(plt, log, title: str, path: Path) -> Path:
    """The passivity guard of a run: both observers (J, summed over the six axes), the energy each
    controller dissipated (J, cumulative), and the slave's position drift (mm, in M)."""
    t = log["t"][: len(log["tdpa_W_master_J"])]
    fig, axes = plt.subplots(3, 1, figsize=(7, 5.4), sharex=True)
    axes[0].plot(t, log["tdpa_W_master_J"].sum(axis=1) * 1e3, lw=0.8, label="master observer W_m")
    axes[0].plot(t, log["tdpa_W_slave_J"].sum(axis=1) * 1e3, lw=0.8, label="slave observer W_s")
    axes[0].set_ylabel("observer [mJ]", fontsize=8)
    axes[1].plot(t, log["tdpa_diss_master_J"].sum(axis=1) * 1e3, lw=0.8, label="master damping")
    axes[1].plot(t, log["tdpa_diss_slave_J"].sum(axis=1) * 1e3, lw=0.8, label="slave velocity correction")
    axes[1].set_ylabel("dissipated [mJ]", fontsize=8)
    axes[2].plot(t, np.linalg.norm(log["tdpa_drift_M"][:, :3], axis=1) * 1e3, lw=0.8, label="|drift|")
    axes[2].set_ylabel("drift [mm, M]", fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
