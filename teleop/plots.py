"""Figure 8- and Figure 10-style plots of a run log (matplotlib, headless Agg backend)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

# (series key in the log, axis label, scale to the plotted unit)
PANELS = {
    "rolling_disk": [
        ("m_height_error_m", "A) height error [µm]", 1e6),
        ("m_upright_error_rad", "B) upright error [mrad]", 1e3),
        ("m_rolling_velocity_m_s", "C) rolling velocity V [mm/s]", 1e3),
        ("m_rolling_error_pct", "D) rolling error [%]", 1.0),
    ],
    "sphere": [
        ("m_sphere_deviation_m", "A) deviation from sphere [µm]", 1e6),
        ("m_normal_angle_error_rad", "B) normal angle error [mrad]", 1e3),
        ("m_normal_force_N", "C) normal force [N]", 1.0),
    ],
    "scalpel": [
        ("m_depth_error_m", "A) blade depth error [µm]", 1e6),
        ("m_blade_tilt_rad", "B) blade tilt [mrad]", 1e3),
        ("m_sideslip_m_per_s", "C) sideways slip [mm/s]", 1e3),
        ("m_cut_speed_m_per_s", "D) cutting speed [mm/s]", 1e3),
    ],
}
FIGURE_NAME = {"rolling_disk": "figure8", "sphere": "figure10", "scalpel": "scalpel"}
# the slave's side of a run with a slave (patient frame); the RCM panel only where a trocar is
SLAVE_PANELS = [
    ("slave_track_m", "A) tip tracking error [µm]", 1e6),
    ("slave_depth_err_m", "B) cut depth error [µm]", 1e6),
    ("slave_dir_err_rad", "C) cut direction error [mrad]", 1e3),
    ("slave_contact_N", "D) tissue contact force [N]", 1.0),
    ("slave_rcm_m", "E) trocar (RCM) error [µm]", 1e6),
]


def _kind(log) -> str | None:
    for kind, panels in PANELS.items():
        if panels[0][0] in log:
            return kind
    return None


def plot_log(log_path, out_dir) -> list[Path]:
    """Write the paper-style figure of a run's log.npz into ``out_dir``; returns the PNG paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    log = dict(np.load(log_path))
    summary = json.loads(str(log.pop("summary")))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    kind = _kind(log)
    written = []
    if kind is not None:
        panels = PANELS[kind]
        fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.0 * len(panels)), sharex=True)
        t = log["t"]
        for ax, (key, label, scale) in zip(axes, panels):
            ax.plot(t, log[key] * scale, lw=0.8)
            ax.set_ylabel(label, fontsize=8)
            ax.grid(alpha=0.3)
        if kind == "sphere" and "m_normal_force_expected_N" in log:
            axes[-1].plot(t, log["m_normal_force_expected_N"], "--", lw=0.8, label="push − m v²/r")
            axes[-1].legend(fontsize=7)
        axes[-1].set_xlabel("time [s]")
        fig.suptitle(f"{summary['scenario']} ({summary['master']} master, {summary['integrator']})", fontsize=9)
        fig.tight_layout()
        path = out_dir / f"{FIGURE_NAME[kind]}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    if "slave_contact_N" in log:
        written.append(_plot_slave(plt, log, summary, out_dir / "incision.png"))
    if "tdpa_W_master_J" in log:
        written.append(plot_passivity(plt, log, f"{summary['scenario']}: passivity guard", out_dir / "passivity.png"))
    fig, ax = plt.subplots(figsize=(7, 2.2))
    ax.plot(log["t"], log["tick_us"], lw=0.5)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("tick [µs]")
    ax.set_yscale("log")
    fig.tight_layout()
    path = out_dir / "tick_time.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)
    return written


def _plot_slave(plt, log, summary, path: Path) -> Path:
    """The slave's panels of ``SLAVE_PANELS`` against time: tracking, depth, direction, the tissue
    force that goes back to the operator, and the trocar error when the scene has one."""
    panels = [p for p in SLAVE_PANELS if p[0] in log]  # the RCM series only where there is a trocar
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 1.8 * len(panels)), sharex=True)
    t = log["t"][: len(log[panels[0][0]])]
    for ax, (key, label, scale) in zip(axes, panels):
        ax.plot(t, log[key] * scale, lw=0.8)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{summary['scenario']}: the slave ({summary['master']} master)", fontsize=9)
    fig.tight_layout()
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
