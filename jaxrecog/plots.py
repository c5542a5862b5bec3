"""Figures of the method and of campaign results (matplotlib, headless Agg).

Each function takes plain data and an output path *stem or file name*, writes
a PNG and an SVG next to each other and returns both paths ``(png, svg)``.
The PNG size is ``figsize * dpi`` pixels exactly (``bbox_inches`` is not
``"tight"``), so callers and tests can rely on it.
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ._files import check_output_file
from .kernels.config_grid import ConfigGrid
from .thesis import TABLE_7_8

__all__ = [
    "DPI",
    "save",
    "figure_paths",
    "score_heatmap",
    "belief_groups",
    "belief_lines",
    "step_labels",
    "eigenimages",
    "occlusion_examples",
    "campaign_bars",
    "case_bars",
    "belief_trace",
    "model_figures",
]

DPI = 100
#: belief_lines draws an object on its own only where it exceeds this probability after some image set
BELIEF_FLOOR = 0.01


def wrap_title(title: str, width: int) -> str:
    """Wrap a title at its commas where it can (so "case iii" stays on one
    line), at spaces only where one comma-separated part is itself too long."""
    lines: list[str] = []
    for part in title.split(", "):
        if lines and len(lines[-1]) + 2 + len(part) <= width:
            lines[-1] += ", " + part
        else:
            if lines:
                lines[-1] += ","
            lines.extend(textwrap.wrap(part, width) or [""])
    return "\n".join(lines)


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``fig`` as ``<stem>.png`` and ``<stem>.svg`` and close it (regular
    files in a folder that exists: :func:`jaxrecog._files.check_output_file`)."""
    plt = _plt()
    png, svg = figure_paths(path)
    for f in (png, svg):
        check_output_file(f, "plot")
    fig.savefig(png, dpi=DPI)
    fig.savefig(svg)
    plt.close(fig)
    return png, svg


def figure_paths(path: str | os.PathLike) -> tuple[Path, Path]:
    """The PNG and SVG files :func:`save` writes for ``path`` (its suffix
    ``.png`` / ``.svg``, if any, replaced): for a command to check before
    its work that they can be written."""
    p = Path(path)
    if p.suffix.lower() in (".png", ".svg"):
        p = p.with_suffix("")
    return p.with_suffix(".png"), p.with_suffix(".svg")


def save_png(fig, path: str | os.PathLike, dpi: int = DPI) -> Path:
    """Lay out ``fig``, write it as one PNG at ``path`` and close it (the
    sweep scripts' single figures; :func:`save` writes PNG + SVG)."""
    plt = _plt()
    fig.tight_layout()
    check_output_file(path, "plot")
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return Path(path)


def score_heatmap(
    scores: np.ndarray,
    positions: Sequence[int],
    path: str | os.PathLike,
    *,
    chosen: Sequence[int] | None = None,
    title: str = "Planner scores",
    label: str = "score (higher = better)",
) -> tuple[Path, Path]:
    """Scores of all configurations as a ``V1 x V2`` heat map (32 x 7 for the
    thesis rig), the chosen configuration boxed.

    Args:
        scores: ``[A]`` flat scores, ``a = ConfigGrid(positions).index(cfg)``.
        positions: positions per camera (1 or 2 cameras; one camera gives a
            ``V1 x 1`` column).
        chosen: the configuration to mark (default: the arg-max).
    """
    plt = _plt()
    scores = np.asarray(scores, dtype=float)
    positions = tuple(int(v) for v in positions)
    if len(positions) not in (1, 2) or scores.shape != (int(np.prod(positions)),):
        raise ValueError(f"scores of shape {scores.shape} do not match positions {positions} "
                         "(1 or 2 cameras)")
    grid = scores.reshape(positions[0], positions[1] if len(positions) == 2 else 1)
    finite = np.isfinite(grid)
    if chosen is None:
        flat = np.where(np.isfinite(scores), scores, -np.inf)
        chosen = ConfigGrid(positions).configuration(int(np.argmax(flat)))
    chosen = tuple(int(c) for c in chosen) + (0,) * (2 - len(chosen))
    V1, V2 = grid.shape
    fig, ax = plt.subplots(figsize=(5.0, 8.0))
    masked = np.ma.masked_where(~finite, grid)
    im = ax.imshow(masked, aspect="auto", cmap="viridis", interpolation="nearest", origin="upper")
    ax.set_xlabel("camera 1 position" if len(positions) == 2 else "(one camera)")
    ax.set_ylabel("camera 0 position")
    ax.set_xticks(range(V2))
    ax.set_xticklabels([str(v) for v in range(V2)] if len(positions) == 2 else [""])
    step = 1 if V1 <= 16 else 4
    ax.set_yticks(range(0, V1, step))
    r, c = chosen
    ax.add_patch(plt.Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2.5))
    ax.plot([], [], "s", mfc="none", mec="red", mew=2, label=f"chosen ({r},{c})"
            if len(positions) == 2 else f"chosen ({r})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.07), frameon=False)
    ax.set_title(title)
    cb = fig.colorbar(im, ax=ax)
    cb.set_label(label)
    fig.subplots_adjust(left=0.14, right=0.92, top=0.94, bottom=0.12)
    return save(fig, path)


def belief_groups(object_probs: np.ndarray, true_object: int | None = None,
                  floor: float = BELIEF_FLOOR) -> tuple[list[int], list[int]]:
    """``(shown, others)``: the objects whose probability exceeds ``floor``
    after some image set (rows after the first, the prior, which every object
    shares), and the true object, each drawn as its own line; the rest, drawn
    as one line of their summed probability (else eight lines at zero hide
    each other under one visible colour); a single such object keeps its line."""
    P = np.asarray(object_probs, dtype=float)
    body = P[1:] if P.shape[0] > 1 else P
    shown = [m for m in range(P.shape[1]) if m == true_object or float(np.nanmax(body[:, m])) > floor]
    others = [m for m in range(P.shape[1]) if m not in shown]
    return (shown, others) if len(others) > 1 else (list(range(P.shape[1])), [])  # one alone hides nothing


def _others_label(others: Sequence[int], floor: float) -> str:
    names = (", ".join(str(m) for m in others) if len(others) <= 6 else f"{len(others)} objects")
    return f"others: {names}\n(each \u2264 {100 * floor:g} %, summed)"


def step_labels(n_steps: int, configurations: Sequence[Sequence[int]] | None) -> list[str]:
    """Tick labels of steps ``0..n_steps-1``: step 0 is the prior; step n
    names the configuration its image set was taken at (``configurations[n-1]``)."""
    configurations = list(configurations or ())
    out = []
    for s in range(n_steps):
        if s == 0:
            out.append("0\nprior" if configurations else "0")
        elif s - 1 < len(configurations):
            out.append(f"{s}\n(" + ",".join(str(int(c)) for c in configurations[s - 1]) + ")")
        else:
            out.append(str(s))
    return out


def belief_lines(
    object_probs: np.ndarray,
    path: str | os.PathLike,
    *,
    true_object: int | None = None,
    title: str = "Belief over objects per step",
    reference: np.ndarray | None = None,
    configurations: Sequence[Sequence[int]] | None = None,
    floor: float = BELIEF_FLOOR,
) -> tuple[Path, Path]:
    """Object probabilities (summed over poses) after each step, one line per
    object that exceeds ``floor`` after some step (:func:`belief_groups`),
    the others as one summed line, like thesis Table 7.8.

    Args:
        object_probs: ``[S, M]``; row 0 is usually the uniform prior.
        true_object: 0-based index; its line is drawn thick.  Legends number
            objects from 0, as the manifest, the CLI and the tables do.
        reference: optional ``[S', M]`` (e.g. Table 7.8) drawn dotted for
            the true object only.
        configurations: the configuration of each image set (step n's is
            ``configurations[n-1]``), written under the step's tick.
    """
    plt = _plt()
    P = np.asarray(object_probs, dtype=float)
    if P.ndim != 2 or P.shape[0] < 1:
        raise ValueError(f"object_probs must be [steps, objects], got shape {P.shape}")
    S, M = P.shape
    R = None if reference is None or true_object is None else np.asarray(reference, dtype=float)
    fig, ax = plt.subplots(figsize=(7.0, 4.5))
    cmap = plt.get_cmap("tab10")
    steps = np.arange(S)
    shown, others = belief_groups(P, true_object, floor)
    for m in shown:
        thick = true_object is not None and m == true_object
        ax.plot(steps, P[:, m], marker="o", lw=5 if thick else 1.3, ms=9 if thick else 5, color=cmap(m % 10),
                label=f"object {m}" + (" (true)" if thick else ""), zorder=2 if thick else 3)  # true line underneath, so ties stay visible
    if others:
        ax.plot(steps, P[:, others].sum(axis=1), marker=".", ls="--", lw=1.0, color="0.55",
                label=_others_label(others, floor), zorder=1)
    if R is not None:
        ax.plot(np.arange(R.shape[0]), R[:, true_object], ls=":", color="k", lw=1.5,
                label=f"thesis Table 7.8 (object {true_object})")
    n_ticks = max(S, 0 if R is None else R.shape[0])  # ticks cover the reference line too
    ax.set_xlabel("step (0 = prior, n = after the n-th image set" + ("; (configuration)" if configurations else "")
                  + ")")
    ax.set_ylabel("P(object | images so far)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks(np.arange(n_ticks))
    ax.set_xticklabels(step_labels(n_ticks, configurations), fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(wrap_title(title, 62), fontsize=10)  # wrapped: the axes are narrower than the figure
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.1, right=0.72, top=0.86, bottom=0.17 if configurations else 0.13)
    return save(fig, path)


def eigenimages(
    mean_image: np.ndarray,
    basis: np.ndarray,
    image_shape: tuple[int, int],
    path: str | os.PathLike,
    *,
    eigenvalues: np.ndarray | None = None,
    n: int = 7,
    title: str = "Eigenimages",
) -> tuple[Path, Path]:
    """The mean image and the first ``n`` eigenimages of one position.

    Args:
        mean_image: ``[D]`` (unit-energy mean, eq. 4.4).
        basis: ``[D, K]`` orthonormal eigenvectors (eq. 4.10).
        eigenvalues: ``[K]``, printed under each eigenimage.
    """
    plt = _plt()
    H, W = image_shape
    basis = np.asarray(basis, dtype=float)
    n = max(1, min(n, basis.shape[1]))
    cols = min(4, n + 1)
    rows = int(np.ceil((n + 1) / cols))
    fig_h = rows * (2.3 * H / W + 0.6) + 0.5
    fig, axes = plt.subplots(rows, cols, figsize=(2.4 * cols, fig_h), squeeze=False)
    tiles = [("mean image", np.asarray(mean_image, float).reshape(H, W), "gray")]
    for k in range(n):
        e = basis[:, k].reshape(H, W)
        sub = f"eigenimage {k}"
        if eigenvalues is not None:
            sub += f"\nλ = {float(np.asarray(eigenvalues)[k]):.3g}"
        tiles.append((sub, e, "RdBu_r"))
    for ax, (name, img, cmap) in zip(axes.flat, tiles):
        if cmap == "RdBu_r":
            s = float(np.abs(img).max()) or 1.0
            ax.imshow(img, cmap=cmap, vmin=-s, vmax=s)
        else:
            ax.imshow(img, cmap=cmap)
        ax.set_title(name, fontsize=9)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in list(axes.flat)[len(tiles):]:
        ax.axis("off")
    fig.suptitle(title + ": mean and eigenimages (red > 0, blue < 0, λ = eigenvalue)", fontsize=11)
    fig.subplots_adjust(left=0.02, right=0.98, top=1.0 - 0.62 / fig_h, bottom=0.02,
                        hspace=0.45, wspace=0.08)
    return save(fig, path)


def occlusion_examples(
    image: np.ndarray,
    path: str | os.PathLike,
    *,
    levels: Sequence[float] = (0.05, 0.10, 0.15, 0.20, 0.25),
    shapes: Sequence[str] | None = None,
    seed: int = 0,
    title: str = "DB2 occluders: shape x level",
) -> tuple[Path, Path]:
    """One training image with an occluder of each shape (rows) and level
    (columns), drawn from the calibrated template bank of
    :mod:`jaxrecog.augment`; the true covered fraction is printed on each."""
    from .augment import SHAPES, make_occluder

    plt = _plt()
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be a gray [H, W] array, got shape {img.shape}")
    H, W = img.shape
    shapes = tuple(SHAPES if shapes is None else shapes)
    levels = tuple(float(x) for x in levels)
    rng = np.random.default_rng(seed)
    fig, axes = plt.subplots(len(shapes), len(levels),
                             figsize=(1.9 * len(levels) + 0.9, 1.55 * len(shapes) + 0.7), squeeze=False)
    for r, shape in enumerate(shapes):
        for c, lev in enumerate(levels):
            t = make_occluder(shape, lev, (H, W), rng)
            h, w = t.shape
            y0 = int(rng.integers(0, H - h + 1))
            x0 = int(rng.integers(0, W - w + 1))
            out = img.copy()
            region = out[y0:y0 + h, x0:x0 + w]
            region[t > 0] = 0
            ax = axes[r, c]
            ax.imshow(out, cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.text(0.03, 0.05, f"{100 * t.sum() / (H * W):.1f} %", transform=ax.transAxes,
                    color="yellow", fontsize=7)
            if r == 0:
                ax.set_title(f"level {100 * lev:g} %", fontsize=9)
            if c == 0:
                ax.set_ylabel(shape, fontsize=9)
    fig.suptitle(title + "  (yellow: fraction of the image covered)", fontsize=10)
    fig.subplots_adjust(left=0.06, right=0.99, top=1.0 - 0.6 / (1.55 * len(shapes) + 0.7), bottom=0.02,
                        hspace=0.15, wspace=0.05)
    return save(fig, path)


def campaign_bars(
    rows: Mapping[str, Sequence],
    path: str | os.PathLike,
    *,
    thesis: Mapping[str, object] | None = None,
    title: str = "Recognition campaign",
) -> tuple[Path, Path]:
    """Recognition rate (with its 95 % Wilson interval as an error bar) and
    mean number of views per object, one bar per planner (named as the CLI
    spells it), the thesis's published values as markers.

    Args:
        rows: planner name -> :class:`~jaxrecog.results.ObjectRow` list from
            :func:`~jaxrecog.results.summarize` (per object, then "Average").
        thesis: planner name -> :class:`~jaxrecog.thesis.ThesisTable` (or
            anything with ``rate``, ``views`` per object and ``average``).
    """
    plt = _plt()
    planners = list(rows)
    if not planners:
        raise ValueError("no campaign results to plot")
    labels = [r.label for r in rows[planners[0]]]
    x = np.arange(len(labels))
    width = 0.8 / len(planners)
    cmap = plt.get_cmap("tab10")
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9.0, 6.5), sharex=True)
    marked = False
    for j, name in enumerate(planners):
        rs = {r.label: r for r in rows[name]}
        rate = np.array([rs[l].rate if l in rs else np.nan for l in labels], float)
        views = np.array([rs[l].views if l in rs else np.nan for l in labels], float)
        xs = x - 0.4 + width * (j + 0.5)
        color = cmap(j % 10)
        ax1.bar(xs, rate, width, color=color, label=name)  # the planner as the CLI spells it
        ax2.bar(xs, views, width, color=color, label=name)
        lo, hi = rate_interval(rows[name], labels)
        ax1.errorbar(xs, rate, yerr=[rate - lo, hi - rate], fmt="none", ecolor="black", elinewidth=0.9,
                     capsize=2, zorder=3)
        for xz in xs[rate == 0]:  # a zero rate is a result, not a missing bar
            ax1.text(xz, 1.0, "0", ha="center", va="bottom", fontsize=8, color=color)
        ref = (thesis or {}).get(name)
        if ref is not None:
            t_rate = list(ref.rate) + [ref.average[0]]
            t_views = list(ref.views) + [ref.average[2]]
            n = min(len(labels), len(t_rate))
            kw = dict(marker="D", ms=5, ls="none", mfc="white", mec="black", mew=1.2, zorder=4)
            ax1.plot(xs[:n], t_rate[:n], label="thesis (published)" if not marked else None, **kw)
            ax2.plot(xs[:n], t_views[:n], **kw)
            marked = True
    ax1.set_ylabel("recognition rate (%)\nbars: 95 % interval", fontsize=9)
    ax1.set_ylim(0, 105)
    ax2.set_ylabel("mean number of views")
    ax2.set_xlabel("object")
    ax2.set_xticks(x)
    ax2.set_xticklabels(labels)
    for ax in (ax1, ax2):
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
    ax1.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False, fontsize=9)
    ax1.set_title(title)
    fig.subplots_adjust(left=0.08, right=0.78, top=0.93, bottom=0.09, hspace=0.12)
    return save(fig, path)


def rate_interval(rows: Sequence, labels: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """The 95 % interval (percent) of each labelled row's rate, NaN where the
    row is missing or has none (:attr:`~jaxrecog.results.ObjectRow.rate_ci`)."""
    by = {r.label: r for r in rows}
    ci = np.array([tuple(getattr(by[l], "rate_ci", (np.nan, np.nan))) if l in by else (np.nan, np.nan)
                   for l in labels], float).reshape(len(labels), 2)
    return ci[:, 0], ci[:, 1]


# -- the figures of a campaign report (``jaxrecog experiment`` / ``demo``) ----------


def case_bars(report, path: str | os.PathLike, *, title: str | None = None) -> tuple[Path, Path]:
    """:func:`campaign_bars` of a :class:`~jaxrecog.campaigns.CaseReport`,
    with the thesis's numbers as markers where the thesis has some
    (:meth:`~jaxrecog.campaigns.CaseReport.thesis_table`: a thesis case on
    the full table); the title says the case, the stride and the trials."""
    rows = dict(report.rows)
    ref = {p: t for p in rows if (t := report.thesis_table(p)) is not None}
    stride = report.settings.stride
    return campaign_bars(rows, path, thesis=ref,
                         title=(title or f"Case ({report.case.name})")
                               + ("" if stride == 1 else f", every {stride}th position")
                               + f": {report.settings.trials_per_object} trials per object"
                               + (", markers: thesis" if ref else ""))


def belief_trace(result, path: str | os.PathLike, *, planner: str, case: str, occluded: bool,
                 thesis_rig: bool) -> tuple[Path, Path]:
    """:func:`belief_lines` of one traced trial (a
    :class:`~jaxrecog.results.TrialResult` with ``object_probs``), the uniform
    prior first; thesis Table 7.8 drawn beside it when the trial is the one
    that table traces (case iii, object 5 -- the thesis's object 6 --, 8 objects, the thesis's rig)."""
    probs = np.asarray(result.object_probs, dtype=float)
    M = probs.shape[1]
    probs = np.vstack([np.full((1, M), 1.0 / M), probs])
    traced = thesis_rig and case == "iii" and result.object == 5 and M == len(TABLE_7_8[0])
    scene = "occluded" if occluded else "clean"
    return belief_lines(probs, path, true_object=result.object, reference=np.asarray(TABLE_7_8) if traced else None,
                        configurations=getattr(result, "configurations", None) or None,
                        title=f"Belief per step: object {result.object}, "
                              f"pose {result.pose}, {planner}, case {case} ({scene})")


def model_figures(model, scores: np.ndarray, folder: str | os.PathLike, *,
                  image: np.ndarray | None = None) -> list[Path]:
    """A model at a glance: ``mi_scores`` (the MI ``scores`` of every
    configuration for the uniform belief), ``eigenimages`` (camera 0, position
    0) and ``occlusion_examples`` of the model's occlusion levels on ``image``
    (a training image; default: camera 0's mean image at position 0)."""
    folder = Path(folder)
    positions = tuple(int(c.basis.shape[0]) for c in model.cameras)
    written = list(score_heatmap(scores, positions, folder / "mi_scores",
                                 title="MI of every configuration, uniform belief", label="MI (nats)"))
    cam = model.cameras[0]
    mean = np.asarray(cam.mean_image[0])
    written += eigenimages(mean, np.asarray(cam.basis[0]), model.image_shape, folder / "eigenimages",
                           eigenvalues=np.asarray(cam.eigenvalues[0]), title="Camera 0, position 0")
    if image is None:
        img = mean.reshape(model.image_shape)
        image = np.clip(255 * (img - img.min()) / max(float(np.ptp(img)), 1e-12), 0, 255).astype(np.uint8)
    written += occlusion_examples(image, folder / "occlusion_examples",
                                  levels=tuple(x for x in model.levels if x > 0) or (0.05, 0.25))
    return written
