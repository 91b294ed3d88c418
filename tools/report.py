"""`naocal diagnose --report DIR`: an HTML page with the diagnosis's tables and plots (matplotlib, Agg).

DIR/index.html plus PNGs beside it: residual scatter before and after adding the top candidate (the paper's
Fig. 4), residual vectors over the image, residuals against the top candidates' regressors, per-stance and
per-image error, the ranking table, parameters with uncertainties, the correlation matrix, and predicted against
detected vertices drawn on the captured images (the paper's Fig. 5) when DATASET/images/ holds them.
"""

from __future__ import annotations

import html
import io
import math
from pathlib import Path

import numpy as np

from naocal.solver.fileio import atomic_write_bytes, atomic_write_text

IMAGE_PATTERNS = ("{:06d}.png", "{:06d}.jpg", "{:d}.png", "{:d}.jpg", "image_{:06d}.png", "image_{:d}.png")
COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown")


def target_colours(targets) -> dict:
    """A colour per target, in the order given (the NAO's sandals L, R: blue, orange)."""
    return {t: COLOURS[k % len(COLOURS)] for k, t in enumerate(dict.fromkeys(targets))}
DPI = 80
MAX_ARROWS = 1200


def find_image(images_dir: Path, image_id: int) -> Path | None:
    """The captured image of `image_id` in DATASET/images/ (naocal writes images/<image:06d>.png)."""
    for pattern in IMAGE_PATTERNS:
        path = images_dir / pattern.format(int(image_id))
        if path.is_file():
            return path
    return None


def write_report(out_dir, diagnosis, *, identify_fit, identify_command=None, dataset_path=None,
                 top_count: int = 2) -> Path:
    """Write DIR/index.html and its PNGs; returns the path of index.html.

    identify_fit(candidate) -> solver.fit.DatasetFit: the fit of the identify command the verdict suggests for
    the candidate (tools.cmd_diagnose: its options through naocal identify's own path: trimming, angle choice,
    GLS), so that the page shows the numbers that command prints, not a fit of its own; identify_command(candidate)
    -> that command's text, shown beside its numbers.
    """
    import matplotlib

    matplotlib.use("Agg")
    from naocal.solver.crossval import grouped_cv_rms
    from naocal.solver.errors import NaocalError

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = diagnosis.result
    data = result.model.data
    # the top candidate a model can take (an assumption only a measurement can settle has no 'after' fit)
    top = next((c for c in diagnosis.candidates if c.testable and c.significant and c.plausible and not c.remedy),
               None)
    fits = {}

    def fit_of(candidate):
        """identify's fit with the candidate (None when these data cannot fit it), each made once."""
        if candidate.effect not in fits:
            try:
                fit = identify_fit(candidate)
            except NaocalError:  # a candidate these data cannot fit: no picture
                fit = None
            fits[candidate.effect] = fit if fit is not None and fit.result.success else None
        return fits[candidate.effect]

    after_fit = fit_of(top) if top is not None else None
    after = after_fit.result if after_fit is not None else None
    cv_before = cv_after = None
    if len({(t, s) for t, s in zip(data.target, data.stance)}) >= 2:
        cv_before = grouped_cv_rms(data, result.registry)
        if after is not None:  # as naocal identify computes its cv_rms_px
            cv_after = grouped_cv_rms(after_fit.data, after.registry)

    figures = {}
    figures["scatter.png"] = _scatter(result, after, top)
    figures["vectors.png"] = _vectors(result, after, top)
    figures["stances.png"] = _stances(diagnosis)
    for k, cand in enumerate([c for c in diagnosis.candidates if c.testable and not c.remedy][:top_count]):
        fit = fit_of(cand)
        # (an assumption's candidate adds no term: no partial residuals to show)
        fig = _regressor_view(fit.result, cand.effect) if fit is not None and not cand.assumption else None
        if fig is not None:
            figures[f"regressors_{k + 1}.png"] = fig
    figures["correlation.png"] = _correlation(after or result)
    overlays = []
    if dataset_path is not None and (Path(dataset_path) / "images").is_dir():
        for entry in diagnosis.location.worst_images[:3]:
            path = find_image(Path(dataset_path) / "images", entry["image"])
            if path is not None:
                name = f"image_{entry['image']:06d}.png"
                figures[name] = _overlay(path, result, after, top, entry["image"])
                overlays.append((name, entry))
    import matplotlib.pyplot as plt

    for name, fig in figures.items():
        atomic_write_bytes(out / name, png_bytes(fig))
        plt.close(fig)
    index = out / "index.html"
    command = identify_command(top) if identify_command is not None and top is not None else None
    atomic_write_text(index, _html(diagnosis, after, top, cv_before, cv_after, figures, overlays, dataset_path,
                                   command))
    for path in [index] + [out / name for name in figures]:
        path.chmod(0o644)  # a report is for reading and sharing
    return index


def png_bytes(fig) -> bytes:
    """The figure as a palette PNG (256 colours): plots lose nothing visible and shrink about threefold."""
    from PIL import Image

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    buffer.seek(0)
    image = Image.open(buffer).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=True)
    return out.getvalue()


# --------------------------------------------------------------------------------------------- figures


def _figure(width, height):
    import matplotlib.pyplot as plt

    return plt.figure(figsize=(width, height), layout="constrained")


def _scatter(result, after, top):
    fig = _figure(9, 4.2)
    fits = [("current model", result)] + ([(_after_title(top), after)] if after is not None else [])
    for k, (title, fit) in enumerate(fits):
        ax = fig.add_subplot(1, len(fits), k + 1)
        r = fit.residuals_px
        target_of_row = fit.model.data.target[fit.model.data.image_of_row]
        for target, colour in target_colours(fit.model.data.target).items():
            rows = target_of_row == target
            ax.scatter(r[rows, 0], r[rows, 1], s=3, alpha=0.5, color=colour, label=f"{target} board", linewidths=0)
        ax.set_title(f"{title}\nRMS {fit.rms_px[0]:.3f} / {fit.rms_px[1]:.3f} px (x / y)", fontsize=10)
        ax.set_xlabel("residual x (px)")
        ax.set_ylabel("residual y (px)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.axhline(0, color="0.7", lw=0.5)
        ax.axvline(0, color="0.7", lw=0.5)
        ax.legend(loc="upper right", fontsize=8, markerscale=3)
    return fig


def _vectors(result, after, top):
    fits = [("current model", result)] + ([(_after_title(top), after)] if after is not None else [])
    fig = _figure(9 if len(fits) > 1 else 5.5, 3.8)
    cameras = result.model.data.cameras.values()
    width, height = max(c.get("width_px", 640) for c in cameras), max(c.get("height_px", 480) for c in cameras)
    # One scale for every panel, so that a shorter arrow after adding an effect is a smaller residual: the
    # largest 95th percentile (the current model's, as a rule) is drawn 30 px long.
    p95 = max(float(np.percentile(np.hypot(*fit.residuals_px.T), 95)) for _, fit in fits)
    scale = 30.0 / max(p95, 1e-9)
    for k, (title, fit) in enumerate(fits):
        ax = fig.add_subplot(1, len(fits), k + 1)
        data, r = fit.model.data, fit.residuals_px
        shown = np.arange(0, data.n_rows, max(1, data.n_rows // MAX_ARROWS))  # keep the picture readable
        target_of_row = data.target[data.image_of_row]
        for target, colour in target_colours(data.target).items():
            rows = shown[target_of_row[shown] == target]
            ax.quiver(data.uv_px[rows, 0], data.uv_px[rows, 1], r[rows, 0] * scale, r[rows, 1] * scale,
                      angles="xy", scale_units="xy", scale=1, color=colour, width=0.003, label=f"{target} board")
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)
        ax.set_aspect("equal")
        same = " (both panels)" if len(fits) > 1 else ""
        ax.set_title(f"{title}: residual x {scale:.3g}{same}\n(predicted - detected, over the image)", fontsize=10)
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        ax.legend(loc="lower right", fontsize=8)
    return fig


def _stances(diagnosis):
    fig = _figure(9, 3.6)
    ax = fig.add_subplot(1, 2, 1)
    stances = sorted(diagnosis.comparison.per_stance, key=lambda s: (s["target"], s["stance"]))
    values = [math.sqrt((s["rms_px"][0] ** 2 + s["rms_px"][1] ** 2) / 2) for s in stances]
    colours = target_colours(diagnosis.result.model.data.target)
    ax.bar(np.arange(len(stances)), values, color=[colours.get(s["target"], "0.5") for s in stances])
    ax.axhline(diagnosis.comparison.noise_px, color="k", ls="--", lw=1, label="noise floor")
    ax.set_xlabel("stance (by target: the NAO's left leg, then right leg)")
    ax.set_ylabel("RMS (px)")
    ax.set_title("error per stance", fontsize=10)
    ax.legend(fontsize=8)
    ax = fig.add_subplot(1, 2, 2)
    split = diagnosis.location.per_image_split
    rigid = np.array([e["rigid_rms_px"] for e in split])
    nonrigid = np.array([e["nonrigid_rms_px"] for e in split])
    ax.bar(np.arange(len(split)), rigid, color="tab:green", label="rigid board motion (kinematics)", width=1.0)
    ax.bar(np.arange(len(split)), nonrigid, bottom=rigid, color="tab:red", label="non-rigid (camera, board)",
           width=1.0)
    ax.set_xlabel("image (as fitted: by target)")
    ax.set_ylabel("RMS (px)")
    ax.set_title("rigid and non-rigid part of each image's error", fontsize=10)
    ax.legend(fontsize=8)
    return fig


def _regressor_view(fit, effect):
    """Partial residuals of `effect` in a fit that has it, against its regressor, with the fitted term as a line.

    Partial residual = residual of the fit with the effect switched off: the effect plus what nothing explains.
    Each effect says what to plot (solver.effect.Effect.partial_residual_panels): joint-level effects the apparent
    per-image joint error against the joint's gravity torque, approach direction or velocity; link lengths the
    apparent per-image length; camera terms per vertex.
    """
    from naocal.solver.effects import EFFECTS

    panels = EFFECTS[effect].partial_residual_panels(fit)
    if not panels:
        return None
    colours = target_colours(fit.model.data.target)
    fig = _figure(max(3.2 * len(panels), 6.0), 3.3)
    for k, (x, y, xlabel, ylabel, groups, line) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1)
        for target, colour in colours.items():
            sel = groups == target
            if sel.any():
                ax.scatter(x[sel], y[sel], s=6, alpha=0.6, color=colour, label=f"{target}", linewidths=0)
        ax.plot(line[0], line[1], color="k", lw=1, label="fitted term")
        ax.axhline(0, color="0.7", lw=0.5)
        ax.set_xlabel(xlabel, fontsize=9)
        ax.set_ylabel(ylabel, fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle(f"{effect}: partial residuals (fitted effect + what remains) against its regressor", fontsize=10)
    return fig


def _correlation(fit):
    from naocal.solver.offsets import shown_name

    names = [shown_name(n) for n in fit.registry.free_names]  # offsets named as c, as the tables show them
    C = np.nan_to_num(fit.correlation)
    size = min(2.5 + 0.22 * len(names), 12)
    fig = _figure(size + 1.2, size)
    ax = fig.add_subplot(1, 1, 1)
    image = ax.imshow(C, cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=6)
    ax.set_yticks(range(len(names)), names, fontsize=6)
    fig.colorbar(image, ax=ax, shrink=0.7, label="correlation")
    ax.set_title("parameter correlation (cluster-robust covariance)", fontsize=10)
    return fig


def _overlay(path, result, after, top, image_id):
    import io

    import matplotlib.image as mpimg

    from naocal.solver.fileio import read_image_bytes

    picture = mpimg.imread(io.BytesIO(read_image_bytes(path)[0]))  # its size checked before it is decoded
    data = result.model.data
    m = int(np.flatnonzero(data.image_id == image_id)[0])
    rows = data.rows_of_images([m])
    detected = data.uv_px[rows]
    fig = _figure(6.4, 5.0)
    ax = fig.add_subplot(1, 1, 1)
    top_value = 255 if picture.dtype == np.uint8 else 1.0
    ax.imshow(picture, cmap="gray" if picture.ndim == 2 else None, vmin=0, vmax=top_value)
    ax.plot(detected[:, 0], detected[:, 1], "o", mfc="none", mec="lime", ms=7, label="detected")
    predicted = detected + result.residuals_px[rows]
    ax.plot(predicted[:, 0], predicted[:, 1], "+", color="red", ms=8, label="predicted (current model)")
    if after is not None and np.any(after.model.data.image_id == image_id):  # (identify may set it aside)
        m_after = int(np.flatnonzero(after.model.data.image_id == image_id)[0])
        rows_after = after.model.data.rows_of_images([m_after])
        predicted_after = after.model.data.uv_px[rows_after] + after.residuals_px[rows_after]
        ax.plot(predicted_after[:, 0], predicted_after[:, 1], "x", color="cyan", ms=6, label=f"with {top.effect}")
    ax.set_title(f"image {image_id} (target {data.target[m]}, stance {data.stance[m]}, head posture "
                 f"{data.head_posture[m]})", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_axis_off()
    return fig


# --------------------------------------------------------------------------------------------- page


def _fmt(value, digits=3):
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def _after_title(top) -> str:
    """'after adding elasticity', or for an assumption's candidate 'without the assumption: ...'."""
    return f"without: {top.assumption}" if top.assumption else f"after adding {top.effect}"


def _shown_effects(fit, top) -> set:
    """The effects whose parameters the 'after' table shows: the candidate's, or those of the parameters an
    assumption's candidate frees (the HipYawPitch pair's joint offsets)."""
    if top.assumption:
        return {fit.registry.parameter(n).effect for n in top.parameters if n in fit.registry.index}
    return {top.effect}


def _parameter_rows(fit, only_effects=None):
    """Table rows of the fitted parameters: joint and head offsets named as the stored c they are ('c LHipPitch'),
    the others under their own names."""
    from naocal.solver.diagnostics import implausibility
    from naocal.solver.offsets import shown_name

    rows = []
    for name, entry in fit.parameters_dict().items():
        effect = fit.registry.parameters[fit.registry.index[name]].effect
        if only_effects is not None and effect not in only_effects:
            continue
        value, unit = fit.registry.display(name, entry["value"])  # as the effect shows it: deg, mm, ms ...
        std, _ = fit.registry.display(name, entry["std"])
        fixed = " (fixed)" if name in fit.registry.fixed else ""
        why = implausibility(fit, name)
        rows.append(f"<tr{' class=bad' if why else ''}><td>{html.escape(shown_name(name))}</td>"
                    f"<td class=n>{value:+.4f}</td><td class=n>{std:.4f}</td><td>{html.escape(unit)}{fixed}</td>"
                    f"<td>{html.escape(why)}</td></tr>")
    return "\n".join(rows)


CSS = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.6em; } th { background: #f0f0f0; }
td.n { text-align: right; font-family: monospace; } tr.sig td { background: #eaf6ea; }
tr.bad td { background: #fbe3e3; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.3em 0; }
.verdict { background: #fff7e0; border-left: 4px solid #e0a000; padding: 0.6em 1em; }
"""


def _html(diagnosis, after, top, cv_before, cv_after, figures, overlays, dataset_path, identify_command) -> str:
    from naocal.agent.summary import describe_direction

    c, loc, res = diagnosis.comparison, diagnosis.location, diagnosis.result
    data = res.model.data
    extra = list(res.registry.extra_effects())
    e = html.escape
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>naocal diagnose</title>"
             f"<style>{CSS}</style></head><body>",
             f"<h1>naocal diagnose: {e(str(dataset_path or 'dataset'))}</h1>",
             f"<p>Model: base{e(''.join(' + ' + x for x in extra))}. {data.n_rows} vertices in {data.n_images} "
             f"images.</p>"]
    if top is not None and after is not None:
        what = (f"The data contradict an assumption of the model: <b>{e(top.assumption)}</b>. Without it"
                if top.assumption else f"Add <b>{e(top.effect)}</b>")
        verdict = (f"{what}: RMS {_fmt(c.rms_total_px)} px &rarr; "
                   f"{_fmt(_mean_rms(after.rms_px))} px "
                   f"(fit), predicted {_fmt(top.predicted_rms_px)} px; noise floor {_fmt(c.noise_px)} px.")
        if cv_before is not None and cv_after is not None:
            verdict += (f" On stances the fit did not see: {_fmt(_mean_rms(cv_before))} px &rarr; "
                        f"{_fmt(_mean_rms(cv_after))} px.")
    else:
        verdict = ("No candidate effect is significant: the model explains these data "
                   + ("to the noise level." if c.ratio_to_noise < 1.5 else "as far as the candidates go."))
    settled = next((x for x in diagnosis.candidates if x.significant and x.plausible), None)
    if settled is not None and settled.remedy and (top is None or settled.excess_rss_px2 > top.excess_rss_px2):
        verdict = (f"The data contradict an assumption of the model: <b>{e(settled.assumption)}</b> (predicted RMS "
                   f"without it {_fmt(settled.predicted_rms_px)} px; noise floor {_fmt(c.noise_px)} px): "
                   f"{e(settled.remedy)}. " + (verdict if top is not None else ""))
    parts.append(f"<p class=verdict>{verdict}</p>")

    parts.append("<h2>Compare</h2><table>"
                 f"<tr><th>RMS x / y</th><td class=n>{_fmt(c.rms_px[0])} / {_fmt(c.rms_px[1])} px</td></tr>"
                 f"<tr><th>noise floor</th><td class=n>{_fmt(c.noise_px)} px</td></tr>"
                 f"<tr><th>detector noise ({e(c.noise_source)})</th>"
                 f"<td class=n>{_fmt(c.detector_noise_px)} px</td></tr>"
                 + (f"<tr><th>joint readings quantised to {math.degrees(c.encoder_resolution_rad):.3g} deg</th>"
                    f"<td class=n>{_fmt(c.encoder_noise_px)} px</td></tr>" if c.encoder_resolution_rad > 0 else "")
                 + 
                 f"<tr><th>fit / noise</th><td class=n>{_fmt(c.ratio_to_noise, 1)}</td></tr>"
                 + (f"<tr><th>cross-validated RMS x / y</th><td class=n>{_fmt(cv_before[0])} / {_fmt(cv_before[1])}"
                    " px</td></tr>" if cv_before is not None else "")
                 + "</table><table><tr><th>group</th><th>RMS x (px)</th><th>RMS y (px)</th><th>images</th></tr>")
    for target, v in c.per_target.items():
        parts.append(f"<tr><td>target {e(target)}</td><td class=n>{_fmt(v['rms_px'][0])}</td>"
                     f"<td class=n>{_fmt(v['rms_px'][1])}</td><td class=n>{v['n_images']}</td></tr>")
    for p, v in c.per_head_posture.items():
        parts.append(f"<tr><td>head posture {p}</td><td class=n>{_fmt(v['rms_px'][0])}</td>"
                     f"<td class=n>{_fmt(v['rms_px'][1])}</td><td class=n>{v['n_images']}</td></tr>")
    parts.append("</table>")
    parts.append("<p>Residuals of every vertex (predicted - detected), "
                 + ("before and after adding the top candidate " if after is not None else "of the current model ")
                 + "(like Fig. 4 of Kastner, R&ouml;fer and Laue):</p><img src='scatter.png' alt='residual scatter'>")
    parts.append("<img src='stances.png' alt='error per stance and per image'>")

    parts.append("<h2>Locate</h2>")
    parts.append(f"<p>Rigid board motion {_fmt(loc.rigid_rms_px)} px, non-rigid remainder "
                 f"{_fmt(loc.nonrigid_rms_px)} px: {100 * loc.rigid_share:.1f} % of the misfit moves the boards "
                 f"rigidly (kinematic chain); the rest points at the camera model or the boards.</p>"
                 f"<p>Boards: {e(loc.board_summary)}.</p>")
    parts.append("<table><tr><th>worst images</th><th>target</th><th>stance</th><th>head posture</th><th>RMS (px)</th>"
                 "<th>rigid</th><th>non-rigid</th></tr>")
    for w in loc.worst_images:
        parts.append(f"<tr><td>{w['image']}</td><td>{e(w['target'])}</td><td>{w['stance']}</td>"
                     f"<td>{w['head_posture']}</td><td class=n>{_fmt(w['rms_total_px'])}</td>"
                     f"<td class=n>{_fmt(w['rigid_rms_px'])}</td><td class=n>{_fmt(w['nonrigid_rms_px'])}</td></tr>")
    parts.append("</table><table><tr><th>misfit explained by a board motion proportional to</th>"
                 "<th>share</th><th>p-value</th></tr>")
    for r in loc.regressors[:10]:
        p_value = (f"<td class=n>{r['p_value']:.1e}</td>" if np.isfinite(r["p_value"])
                   else "<td>not testable (too few images carry it)</td>")
        parts.append(f"<tr><td>{e(r['regressor'])}</td><td class=n>{100 * r['explained_share']:.1f} %</td>"
                     f"{p_value}</tr>")
    parts.append("</table><img src='vectors.png' alt='residual vectors over the image'>")
    for name in sorted(n for n in figures if n.startswith("regressors_")):
        parts.append(f"<img src='{name}' alt='residual against regressor'>")

    parts.append("<h2>Names: candidate effects, best first</h2>")
    parts.append(f"<p>Score test of each effect not yet in the model; significant when p &lt; "
                 f"{diagnosis.threshold:.1e} (family-wise 0.001, Bonferroni; clustered by stance). "
                 "Explains: share of the misfit it would remove beyond what its parameters would fit of pure noise "
                 "(the ranking). Uniqueness: share of the effect's signature the model cannot already produce.</p>")
    parts.append("<table><tr><th>effect</th><th>explains</th><th>predicted RMS (px)</th><th>p-value</th>"
                 "<th>significant</th><th>uniqueness</th><th>dof</th><th>note</th></tr>")
    rss = c.rms_total_px ** 2 * 2 * data.n_rows
    for cand in diagnosis.candidates:
        if not cand.testable:
            parts.append(f"<tr><td>{e(cand.effect)}</td><td>-</td><td>-</td><td>-</td><td>-</td><td>-</td><td>-</td>"
                         f"<td>not testable: {e(cand.reason)}</td></tr>")
            continue
        note = "implausible size: " + ", ".join(cand.implausible[:2]) if cand.implausible else ""
        if cand.inside_model:
            note = "; ".join(filter(None, [note, "indistinguishable: " + ", ".join(cand.inside_model[:2])]))
        share = 100 * max(cand.excess_rss_px2, 0.0) / rss if rss > 0 else 0.0
        parts.append(f"<tr class='{'sig' if cand.significant else ''}'><td>{e(cand.effect)}</td>"
                     f"<td class=n>{share:.1f} %</td><td class=n>{_fmt(cand.predicted_rms_px)}</td>"
                     f"<td class=n>{cand.p_value:.1e}</td>"
                     f"<td>{'yes' if cand.significant else 'no'}</td><td class=n>{_fmt(cand.uniqueness)}</td>"
                     f"<td class=n>{cand.dof}</td><td>{e(note)}</td></tr>")
    parts.append("</table>")

    header = "<tr><th>parameter</th><th>value</th><th>std</th><th>unit</th><th>note</th></tr>"
    parts.append("<h2>Parameters</h2><p>Joint offsets as stored: c (added to commands, subtracted from readings; "
                 "q_true = theta - c); camera rotation, board mount and effects as the model's values.</p>"
                 f"<table>{header}")
    parts.append(_parameter_rows(res))
    parts.append("</table>")
    if after is not None:
        parts.append(f"<p>{e(_after_title(top)).capitalize()}: the fit of <code>{e(identify_command or '')}</code> "
                     "(naocal identify's: corners and images set aside, angles chosen, generalised least squares "
                     f"where it applies; all parameters refitted):</p><table>{header}"
                     + _parameter_rows(after, _shown_effects(after, top)) + "</table>")
    weak = "".join(f"<li>relative singular value {w.singular_value:.1e}: {e(describe_direction(w))}</li>"
                   for w in (after or res).weak_directions)
    parts.append(f"<p>Weakest parameter combinations:</p><ul>{weak}</ul>")
    parts.append("<img src='correlation.png' alt='correlation matrix'>")
    if overlays:
        parts.append("<h2>Captured images</h2><p>Detected vertices (green circles) against the current model's "
                     "prediction (red +)" + (" and the prediction with the top candidate (cyan x)" if after is not None
                                             else "") + ", worst images first (like Fig. 5 of the paper).</p>")
        for name, entry in overlays:
            parts.append(f"<img src='{name}' alt='image {entry['image']}'>")
    warnings = (after or res).warnings
    if warnings:
        parts.append("<h2>Warnings</h2><ul>" + "".join(f"<li>{e(w)}</li>" for w in warnings) + "</ul>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def _mean_rms(xy):
    return math.sqrt((xy[0] ** 2 + xy[1] ** 2) / 2)
