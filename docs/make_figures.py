"""Figures of the simulator for the README: ``python docs/make_figures.py``.

Writes, beside this script:

- ``waterfall.png``: one camera's lines stacked scan after scan (a waterfall, scans x pixels)
  over two spans of line with an overlap, at night (the rig's blue strobe) and by day with
  white lamps, from the same scene and the same run; with full-resolution close-ups of a
  dropper and of a registration (steady arm).
- ``line.png``: one line through the overlap by day with the blue strobe behind band-pass
  filters (the paper's figure 5 situation), with the objects marked from the ground truth,
  and a close-up of one contact wire with its worn face (the paper's figures 2b and 7).

Needs matplotlib. Deterministic: the same seed gives the same pictures.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from catenary_linescan.simulator.rig import load_rig
from catenary_linescan.simulator.settings import DEMO_RIG_PATH, parse_settings
from catenary_linescan.simulator.simulation import Simulation

HERE = Path(__file__).resolve().parent
SEED = 7
CAMERA = "cam2"
LENGTH_M = 110.0


def simulate(lighting: str, camera: str = CAMERA, **extra) -> Simulation:
    rig = load_rig(DEMO_RIG_PATH)
    one = dataclasses.replace(rig, cameras=(rig.camera(camera),))
    settings = {
        "rig": one,
        "length_m": LENGTH_M,
        "seed": SEED,
        "lighting": lighting,
        "overlap": True,
        "curve_radius_m": 0.0,
        "speed_kmh": 40.0,
        "scan_rate_hz": 1000.0,
        "chunk_scans": 512,
    }
    settings.update(extra)
    return Simulation(parse_settings(settings))


def render_all(sim: Simulation):
    lines = []
    chainage = []
    for chunk in sim.chunks():
        lines.append(chunk.lines[CAMERA])
        chainage.append(chunk.truth.chainage_m)
    return np.concatenate(lines), np.concatenate(chainage)


def waterfall() -> None:
    night_sim = simulate("night")
    day_sim = simulate("day-white")
    night, chainage = render_all(night_sim)
    day, _ = render_all(day_sim)
    scene = night_sim.scene
    fit = scene.fittings
    c0, c1 = float(chainage[0]), float(chainage[-1])
    masts = [m for m in scene.masts if c0 <= m.chainage_m <= c1]

    # close-ups: a dropper clamp on the running wire, and a registration
    def scans_near(c: float, half: int) -> slice:
        i = int(np.argmin(np.abs(chainage - c)))
        return slice(max(i - half, 0), min(i + half, chainage.shape[0]))

    drop = fit.chainage_m[(fit.kind == "dropper") & (fit.chainage_m > c0 + 20)]
    dropper_c = float(drop[np.argmin(np.abs(drop - (c0 + 0.3 * (c1 - c0))))])
    arm_c = masts[len(masts) // 2].chainage_m

    fig = plt.figure(figsize=(16, 11))
    grid = fig.add_gridspec(2, 4, width_ratios=[1.0, 1.0, 0.55, 0.55], hspace=0.28, wspace=0.25)
    extent = (-0.5, night.shape[1] - 0.5, c1, c0)
    for k, (image, title) in enumerate(
        ((night, "night, blue strobe + band-pass"), (day, "day, white lamps"))
    ):
        ax = fig.add_subplot(grid[:, k])
        # one display row averages several scans (the figure is ~1000 px tall)
        step = max(1, image.shape[0] // 1100)
        rows = image.shape[0] // step * step
        shown = image[:rows].reshape(-1, step, image.shape[1]).mean(axis=1)
        vmax = 160 if k == 0 else 255
        ax.imshow(
            shown,
            cmap="gray",
            vmin=0,
            vmax=vmax,
            aspect="auto",
            extent=extent,
            interpolation="antialiased",
        )
        ax.set_title(f"{CAMERA}: {title}", fontsize=11)
        ax.set_xlabel("pixel")
        if k == 0:
            ax.set_ylabel("chainage (m)")
        for mast in masts:
            ax.axhline(mast.chainage_m, color="tab:orange", lw=0.6, ls=":", alpha=0.8)
            ax.text(
                night.shape[1] - 30,
                mast.chainage_m - 0.6,
                f"mast {mast.code}",
                color="tab:orange",
                fontsize=8,
                ha="right",
                va="bottom",
            )
        ax.axhline(dropper_c, color="tab:cyan", lw=0.6, ls="--", alpha=0.7)
        ax.text(30, dropper_c - 0.6, "dropper", color="tab:cyan", fontsize=8, va="bottom")
    _, j1, _ = scene.overlap_masts
    mid = scene.masts[j1].chainage_m
    fig.axes[0].text(60, mid + 3.0, "overlap:\ntwo contact\nwires", color="w", fontsize=9)
    # label the wires on the day image from the ground truth
    day_ax = fig.axes[1]
    label_c = c0 + 0.36 * (c1 - c0)
    chunk = day_sim.chunk(int(np.argmin(np.abs(chainage - label_c))) // day_sim.chunk_scans)
    row = int(np.argmin(np.abs(chunk.truth.chainage_m - label_c)))
    cam_truth = chunk.truth.cameras[CAMERA]
    placed = 0
    for m in sorted(range(len(scene.wires)), key=lambda m: np.nan_to_num(cam_truth.u_px[row, m])):
        wire = scene.wires[m]
        u = cam_truth.u_px[row, m]
        if not np.isfinite(u):
            continue
        text = f"contact wire {wire.name[-1]}" if wire.contact else f"messenger {wire.name[-1]}"
        colour = "yellow" if wire.contact else "cyan"
        day_ax.annotate(
            text,
            xy=(u, label_c),
            xytext=(3300 if u > 2000 else 80, label_c - 5 + 3.2 * placed),
            color=colour,
            fontsize=8.5,
            va="center",
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 0.7},
        )
        placed += 1
    for row, (centre, label, half) in enumerate(
        ((dropper_c, "dropper and its clamp", 60), (arm_c, "registration: steady arm", 60))
    ):
        part = scans_near(centre, half)
        for k, image in enumerate((night, day)):
            ax = fig.add_subplot(grid[row, 2 + k])
            piece = image[part]
            cols = np.flatnonzero(np.ptp(piece.astype(int), axis=0) > 40)
            if cols.size:
                lo = max(int(cols.min()) - 60, 0)
                hi = min(int(cols.max()) + 60, image.shape[1])
            else:
                lo, hi = 0, image.shape[1]
            ax.imshow(
                piece[:, lo:hi],
                cmap="gray",
                vmin=0,
                vmax=60 if k == 0 else 255,
                aspect="auto",
                interpolation="nearest",
                extent=(lo - 0.5, hi - 0.5, chainage[part][-1], chainage[part][0]),
            )
            when = "night, display x4" if k == 0 else "day, white"
            ax.set_title(f"{label}\n({when}, every scan)", fontsize=9)
            ax.set_xlabel("pixel", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.ticklabel_format(useOffset=False, axis="y")
    fig.suptitle(
        f"Simulated waterfall (scans x pixels): demo rig {CAMERA} (4096 px), {LENGTH_M:.0f} m of "
        "line at 40 km/h and 1000 scans/s. The contact wire zigzags between registrations\n"
        "(bright worn face at night, dark silhouette by day), its messenger above; body roll "
        "and sway move both in the image.",
        fontsize=11,
    )
    fig.savefig(HERE / "waterfall.png", dpi=100)
    plt.close(fig)


def line_figure() -> None:
    sim = simulate("day-filter", camera=CAMERA)
    scene = sim.scene
    mid_c = scene.masts[scene.overlap_masts[1]].chainage_m
    # a scan 3 m past the overlap's middle mast: both contact wires run, 200 mm apart
    target = mid_c + 3.0
    index = next(
        i
        for i in range(sim.chunk_count)
        if sim.motion.chainage_m(sim.motion.scan_times(min((i + 1) * 512, sim.scans) - 1, 1))[0]
        >= target
    )
    chunk = sim.chunk(index)
    row = int(np.argmin(np.abs(chunk.truth.chainage_m - target)))
    line = chunk.lines[CAMERA][row].astype(float)
    truth = chunk.truth
    cam = truth.cameras[CAMERA]
    names = [w.name for w in scene.wires]
    present = [
        m for m in range(len(names)) if truth.present[row, m] and np.isfinite(cam.u_px[row, m])
    ]

    fig = plt.figure(figsize=(15, 8.5))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 1.25], width_ratios=[1.6, 1.0], hspace=0.35)
    full = fig.add_subplot(grid[0, :])
    region = fig.add_subplot(grid[1, 0])
    close = fig.add_subplot(grid[1, 1])
    u_all = np.arange(line.shape[0])
    full.plot(u_all, line, lw=0.6, color="k")
    full.set_xlim(0, line.shape[0] - 1)
    full.set_ylim(0, 255)
    full.set_ylabel("grey level (8 bit)")
    full.set_xlabel("pixel u")
    full.set_title(
        f"One line of the demo rig's {CAMERA} (4096 px) at chainage {truth.chainage_m[row]:.2f} m, "
        "in an overlap, by day with the blue strobe behind band-pass filters",
        fontsize=11,
    )
    lo = int(min(cam.left_px[row, m] for m in present)) - 80
    hi = int(max(cam.right_px[row, m] for m in present)) + 80
    full.axvspan(lo, hi, color="tab:orange", alpha=0.12)
    full.text(lo, 235, "enlarged below", color="tab:orange", fontsize=9)
    full.text(
        150,
        np.median(line) + 10,
        "background: the sky through the filter (dim, clouds)",
        fontsize=9,
        color="0.3",
    )

    region.plot(u_all[lo:hi], line[lo:hi], lw=0.8, color="k")
    region.set_xlim(lo, hi)
    region.set_ylim(0, 255)
    region.set_xlabel("pixel u")
    region.set_ylabel("grey level")
    colours = {"CW": "tab:red", "MW": "tab:blue"}
    for k, m in enumerate(sorted(present, key=lambda m: cam.u_px[row, m])):
        name = names[m]
        u = cam.u_px[row, m]
        colour = colours[name[:2]]
        region.axvspan(cam.left_px[row, m], cam.right_px[row, m], color=colour, alpha=0.15)
        if name.startswith("CW"):
            text = (
                f"contact wire {name[-1]}\nheight {truth.height_mm[row, m]:.0f} mm, "
                f"stagger {truth.stagger_mm[row, m]:+.0f} mm\n"
                f"w0 = {truth.wear_width_mm[row, m]:.2f} mm "
                f"(h = {truth.residual_thickness_mm[row, m]:.2f} mm)"
            )
            y_text = 205 - 45 * (k % 2)
        else:
            text = f"messenger {name[-1]}\n(dark on the sky)"
            y_text = 70 + 35 * (k % 2)
        region.annotate(
            text,
            xy=(u, line[round(u)]),
            xytext=(u + 12 if u < lo + 0.6 * (hi - lo) else u - 0.3 * (hi - lo), y_text),
            fontsize=8.5,
            color=colour,
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 0.8},
        )
    region.set_title("the objects: shaded spans are the true silhouettes", fontsize=10)

    worn = [m for m in present if names[m].startswith("CW")]
    m = max(worn, key=lambda m: truth.wear_width_mm[row, m])
    u = cam.u_px[row, m]
    a, b = cam.face_left_px[row, m], cam.face_right_px[row, m]
    lo2, hi2 = int(cam.left_px[row, m]) - 12, int(cam.right_px[row, m]) + 13
    x = np.arange(lo2, hi2)
    close.plot(x, line[lo2:hi2], ".-", color="k", lw=0.8, ms=3)
    top = line[lo2:hi2].max()
    close.axvspan(a, b, color="tab:red", alpha=0.15)
    for pos, label in ((a, "A"), (b, "B")):
        close.axvline(pos, color="tab:red", lw=0.8)
        close.text(pos, top * 1.05, label, color="tab:red", ha="center")
    close.axvline(u, color="tab:green", lw=0.8, ls="--")
    close.text(u, top * 1.05, "C", color="tab:green", ha="center")
    for edge in (cam.left_px[row, m], cam.right_px[row, m]):
        close.axvline(edge, color="0.4", lw=0.8, ls=":")
    close.set_ylim(0, top * 1.15)
    close.set_xlabel("pixel u")
    close.set_title(
        f"contact wire {names[m][-1]}: worn face A-B (true edges), its centre C,\n"
        f"silhouette dotted; w0 = {truth.wear_width_mm[row, m]:.2f} mm = {b - a:.1f} px "
        f"at {truth.z_roof_mm[row, m]:.0f} mm above the roof",
        fontsize=9.5,
    )
    fig.savefig(HERE / "line.png", dpi=110, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    waterfall()
    line_figure()
    print(f"wrote {HERE / 'waterfall.png'} and {HERE / 'line.png'}")
