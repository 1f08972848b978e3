"""report.html: a self-contained page (figures embedded as PNG data) for one video.

Coverage over time for both branches (the geometric one faded by its support) and combined, with
deficient segments highlighted, the learned against geometric scatter, sample frames with their
depth, the unrolled map of seen and missed wall, a rendered image of the reconstruction, and
the segment table.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from hybrid import workdir as W
from hybrid.crosscheck import CLASS_NAMES, CrossCheck
from hybrid.ingest import Ingested
from learned.coverage_eval import CLASS_EDGES


def _png(fig) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buffer.getvalue()).decode()


def _img(data: str, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def coverage_over_time(table: CrossCheck) -> str:
    """Each segment's learned, geometric (opacity 0.2 + 0.8 x its support) and combined
    coverage as a line over its time range; deficient segments shaded, unassessable hatched."""
    fig, ax = plt.subplots(figsize=(10, 3.2))
    for row in table.rows:
        if row.deficient:
            ax.axvspan(row.start_s, row.end_s, color="#d62728", alpha=0.15, lw=0)
        if not row.assessable:
            ax.axvspan(row.start_s, row.end_s, color="0.6", alpha=0.3, lw=0, hatch="//")
    lines = (("learned", "#1f77b4", 2.5, "learned"),
             ("geometric", "#ff7f0e", 2.5, "geometric (faded by its support)"),
             ("coverage", "black", 1.2, "combined (read by the deficient rule)"))
    labelled = set()
    for key, colour, width, label in lines:
        for row in table.rows:
            value = getattr(row, key)
            if value is None:
                continue
            support = row.geometric_support if key == "geometric" else None
            ax.plot([row.start_s, row.end_s], [value, value], color=colour, lw=width,
                    alpha=1.0 if support is None else 0.2 + 0.8 * support,
                    label=None if key in labelled else label)
            labelled.add(key)
    for edge in CLASS_EDGES:
        ax.axhline(edge, color="0.7", lw=0.8, ls="--")
    ax.set(xlabel="time (s)", ylabel="segment coverage", ylim=(0, 1),
           title="coverage over time (red: deficient, hatched: not assessable)")
    if labelled:
        legend = ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize=8)
        for handle in legend.legend_handles:
            handle.set_alpha(1.0)  # the key, not the first segment's opacity
    fig.tight_layout()
    return _png(fig)


def branch_scatter(table: CrossCheck) -> str | None:
    both = [(r.geometric, r.learned) for r in table.rows if r.geometric is not None]
    if not both:
        return None
    g, learned = np.array(both).T
    fig, ax = plt.subplots(figsize=(4.2, 4.2))
    ax.scatter(g, learned, s=25)
    ax.plot([0, 1], [0, 1], "k--", lw=1)
    for edge in CLASS_EDGES:
        ax.axvline(edge, color="0.8", lw=0.8)
        ax.axhline(edge, color="0.8", lw=0.8)
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="geometric coverage", ylabel="learned coverage",
           title=f"agreement (3 classes): {table.agreement:.0%}")
    ax.set_aspect("equal")
    fig.tight_layout()
    return _png(fig)


def sample_frames(out: Path, count: int = 6) -> str:
    frames = np.load(out / W.FRAMES, mmap_mode="r")
    depth = np.load(out / W.DEPTH, mmap_mode="r")
    picks = np.linspace(0, len(frames) - 1, count).astype(int)
    fig, axes = plt.subplots(2, count, figsize=(2.0 * count, 3.6))
    for k, t in enumerate(picks):
        axes[0, k].imshow(frames[t])
        axes[0, k].set_title(f"frame {t}", fontsize=8)
        axes[1, k].imshow(np.asarray(depth[t], np.float32), cmap="magma_r")
        for ax in axes[:, k]:
            ax.axis("off")
    axes[1, 0].set_title("depth (near: light)", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def render_mesh(mesh_path: Path, size: tuple[int, int] = (360, 640)) -> str | None:
    """Orthographic view of the mesh along its thinnest axis, Lambert-shaded vertex colours."""
    import open3d as o3d

    from fusion.tsdf import FusedMesh

    mesh = FusedMesh.load(mesh_path)
    vertices = mesh.vertices
    centre = vertices.mean(0)
    _, _, axes = np.linalg.svd(vertices - centre, full_matrices=False)
    along, across, view = axes
    extent = np.abs((vertices - centre) @ np.stack([along, across]).T).max(0) * 1.05
    height, width = size
    scale = max(extent[0] / (width / 2), extent[1] / (height / 2))
    v, u = np.mgrid[:height, :width]
    origins = (centre + ((u - width / 2) * scale)[..., None] * along
               + ((height / 2 - v) * scale)[..., None] * across
               - view * (np.abs((vertices - centre) @ view).max() + 1.0))
    rays = np.concatenate([origins, np.broadcast_to(view, origins.shape)], -1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    ids = hit["primitive_ids"].numpy()
    valid = ids != scene.INVALID_ID
    image = np.ones((height, width, 3))
    if not valid.any():
        return None
    tri = mesh.triangles[ids[valid]]
    uv = hit["primitive_uvs"].numpy()[valid]
    weights = np.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
    colours = (mesh.colors.astype(float) / 255 if mesh.colors is not None
               else np.full((len(vertices), 3), 0.8))
    colour = (colours[tri] * weights[..., None]).sum(1)
    normals = hit["primitive_normals"].numpy()[valid]
    image[valid] = colour * (0.35 + 0.65 * np.abs(normals @ view))[:, None]
    fig, ax = plt.subplots(figsize=(width / 90, height / 90))
    ax.imshow(image.clip(0, 1))
    ax.set_title("reconstruction (TSDF mesh, seen from outside)")
    ax.axis("off")
    fig.tight_layout()
    return _png(fig)


def _table(table: CrossCheck) -> str:
    def fmt(value) -> str:
        if value is None:
            return "—"
        if isinstance(value, bool):
            return "yes" if value else "no"
        return f"{value:.3f}" if isinstance(value, float) else str(value)

    head = ("segment", "time (s)", "learned", "geometric", "geometric support", "difference",
            "learned class", "geometric class", "agree", "coverage", "deficient", "assessable")
    lines = ["<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
    for r in table.rows:
        classes = [None if c is None else CLASS_NAMES[c]
                   for c in (r.learned_class, r.geometric_class)]
        cells = (r.index, f"{r.start_s:.1f}–{r.end_s:.1f}", r.learned, r.geometric,
                 r.geometric_support, r.difference, classes[0], classes[1], r.agree,
                 r.coverage, r.deficient, r.assessable)
        style = ' class="deficient"' if r.deficient else ""
        lines.append(f"<tr{style}>" + "".join(f"<td>{fmt(c)}</td>" for c in cells) + "</tr>")
    return "\n".join(lines + ["</table>"])


def write_report(out: Path, table: CrossCheck, ingested: Ingested) -> Path:
    """Write out/report.html."""
    out = Path(out)
    parts = [f"<h1>C2D2 coverage report: {html.escape(Path(ingested.source).name)}</h1>",
             f"<p>{ingested.frames} frames at {ingested.fps:g} fps "
             f"({ingested.frames / ingested.fps:.1f} s), input {ingested.input_width}×"
             f"{ingested.input_height}. Deficient: coverage below {table.deficient_below:g}; "
             f"assessable: at least {table.min_usable_fraction:.0%} usable frames; "
             f"geometric support: the share of a segment's expected wall that the "
             f"reconstruction reached (the rest is its lumen continued straight); coverage: "
             f"the branches combined, the geometric value weighted "
             f"{table.geometric_weight:g} × its support against the learned one's 1. "
             f"Branch agreement (3 classes): "
             f"{'n/a' if table.agreement is None else f'{table.agreement:.0%}'}.</p>"]
    if ingested.decode_warning:
        parts.append(f"<p class='warn'>{html.escape(ingested.decode_warning)}</p>")
    if table.geometric_error:
        parts.append(f"<p class='warn'>Geometric branch failed: "
                     f"{html.escape(table.geometric_error)}</p>")
    parts += [f"<p class='warn'>No geometric value for segment {r.index} (its verdict rests on "
              f"the learned value): {html.escape(r.geometric_error)}</p>"
              for r in table.rows if r.geometric_error]
    parts += ["<h2>Coverage over time</h2>", _img(coverage_over_time(table), "coverage"),
              "<h2>Segments</h2>", _table(table)]
    scatter = branch_scatter(table)
    if scatter:
        parts += ["<h2>Learned against geometric</h2>", _img(scatter, "scatter")]
    parts += ["<h2>Sample frames and depth</h2>", _img(sample_frames(out), "frames")]
    map_png = out / W.MAPS / "coverage_map.png"
    if map_png.is_file():
        parts += ["<h2>Unrolled wall: seen and missed</h2>",
                  _img(base64.b64encode(map_png.read_bytes()).decode(), "map")]
    if (out / W.MESH).is_file():
        rendering = render_mesh(out / W.MESH)
        if rendering:
            parts += ["<h2>Reconstruction</h2>", _img(rendering, "mesh")]
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;"
             "padding:3px 6px}tr.deficient{background:#fdd}.warn{color:#b00}img{max-width:100%}")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>C2D2 report</title>"
            f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
    return W.write_text(out / W.REPORT, page)
