"""PNG charts of a run_all result (matplotlib, Agg backend, small files)."""
import math
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402

DPI = 72
STYLE = {
    "ours_bake": dict(color="C0", marker="o", label="photon lightmap (ours, lookup)"),
    "ours_bake_gather": dict(color="C4", marker="P", label="photon lightmap (ours, final gather)"),
    "photon_map": dict(color="C2", marker="s", label="photon map, k nearest"),
    "cycles_bake": dict(color="C3", marker="^", label="Cycles bake"),
    "cycles_bake_ss": dict(color="C3", marker="v", ls="--", label="Cycles bake, finer pixels averaged per texel"),
    "cycles_bake_ss_oidn": dict(color="C3", marker="v", ls=":", mfc="none",
                                label="Cycles bake, finer pixels averaged, + OIDN"),
    "ours_bake_cache": dict(color="C8", marker="*", label="photon lightmap (ours, irradiance cache)"),
    "ours_bake_gather_oidn": dict(color="C4", marker="P", ls=":", mfc="none", label="final gather + OIDN"),
    "cycles_bake_oidn": dict(color="C3", marker="^", ls=":", mfc="none", label="Cycles bake + OIDN"),
    "ours_render_constant": dict(color="C0", marker="o", ls="--", label="ours, constant lookup"),
    "ours_render_bilinear": dict(color="C1", marker="D", label="ours, bilinear lookup"),
    "ours_render_gather": dict(color="C4", marker="P", label="ours, final gather"),
    "cycles_render": dict(color="C3", marker="^", label="Cycles render"),
    "luxcore_path": dict(color="C5", marker="v", label="LuxCore path"),
    "luxcore_photongi": dict(color="C6", marker="X", label="LuxCore path + PhotonGI"),
    "ours_bake_oidn": dict(color="C0", marker="o", ls=":", mfc="none", label="photon lightmap + OIDN"),
    "ours_render_gather_oidn": dict(color="C4", marker="P", ls=":", mfc="none", label="final gather + OIDN"),
    "ours_floor_constant": dict(color="C0", marker="o", ls="--", label="constant lookup"),
    "ours_floor_bilinear": dict(color="C1", marker="D", label="bilinear lookup"),
}


def _curve(points, scene, method, x="seconds", y="rel_rmse"):
    c = sorted((p for p in points if p["scene"] == scene and p["method"] == method), key=lambda p: p["knob"])
    return [p[x] for p in c], [max(p[y], 1e-5) for p in c], c


def _save(fig, path, files, dpi=DPI):
    # Noise images compress badly: the error maps use a lower dpi to stay < 150 KB.
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    files.append(str(path))


def _srgb(x):
    x = np.clip(np.nan_to_num(x), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _mosaic(stack):
    """(n, res, res, C) lightmaps side by side, rows flipped to top-down for display."""
    return np.concatenate([m[::-1] for m in stack], axis=1)


def error_vs_time(result, out, files):
    pts = result["points"]
    for info in result["scenes"]:
        sc = info["scene"]
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        for ax, kind, methods, floor in (
                (axes[0], "baked lightmaps, texel by texel",
                 ("ours_bake", "ours_bake_gather", "ours_bake_cache", "ours_bake_oidn", "ours_bake_gather_oidn",
                  "photon_map",
                  "cycles_bake", "cycles_bake_ss", "cycles_bake_oidn", "cycles_bake_ss_oidn"),
                 info["bake_noise_floor"]),
                (axes[1], "renders, pixel by pixel",
                 ("ours_render_constant", "ours_render_bilinear", "ours_render_gather", "ours_render_gather_oidn",
                  "cycles_render", "luxcore_path", "luxcore_photongi"), info["render_noise_floor"])):
            for m in methods:
                xs, ys, c = _curve(pts, sc, m)
                if not xs:
                    continue
                ax.loglog(xs, ys, **STYLE[m])
                for p, xx, yy in ((c[0], xs[0], ys[0]), (c[-1], xs[-1], ys[-1])):
                    k = p["knob"]
                    lab = f"{k / 1e6:g}M" if k >= 1e6 else (f"{k / 1e3:g}k" if k >= 1e3 else f"{k} spp")
                    ax.annotate(lab, (xx, yy), fontsize=7, textcoords="offset points", xytext=(3, 3))
            ax.axhline(floor, color="0.6", ls=":", lw=1, label="reference noise (removed)")
            # Minor-tick labels on a short log axis overlap; the major decades suffice.
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel("wall-clock seconds (2 cores)")
            ax.set_ylabel("relative RMSE vs converged Cycles")
            ax.set_title(f"{sc}: {kind}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        _save(fig, out / f"{sc}_error_vs_time.png", files)


def memory_vs_error(result, out, files):
    pts = result["points"]
    scenes = [i["scene"] for i in result["scenes"]]
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 3.8), squeeze=False)
    for ax, sc in zip(axes[0], scenes):
        for m, key, extra in (("ours_bake", "memory_bytes", dict(label="lightmaps, engine arrays")),
                              ("ours_bake", "memory_compact_bytes",
                               dict(label="lightmaps, 12 B/texel", ls=":", marker="o", mfc="none")),
                              ("photon_map", "memory_bytes", dict(label="photon map, arrays + kd-tree")),
                              ("photon_map", "memory_compact_bytes",
                               dict(label="photon map, 20 B/photon", ls=":", marker="s", mfc="none"))):
            c = sorted((p for p in pts if p["scene"] == sc and p["method"] == m), key=lambda p: p["knob"])
            if not c:
                continue
            st = dict(STYLE[m])
            st.update(extra)
            ax.loglog([max(p["rel_rmse"], 1e-5) for p in c], [p[key] for p in c], **st)
        ax.set_xlabel("relative RMSE (baked texels)")
        ax.set_ylabel("bytes")
        ax.set_title(f"{sc}: memory against error", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.invert_xaxis()
        ax.legend(fontsize=6)
    fig.tight_layout()
    _save(fig, out / "memory_vs_error.png", files)


def error_vs_photons(result, out, files):
    pts = result["points"]
    fig, ax = plt.subplots(figsize=(6, 4))
    for i, info in enumerate(result["scenes"]):
        sc = info["scene"]
        xs, ys, _ = _curve(pts, sc, "ours_bake", x="knob")
        if not xs:
            continue
        ax.loglog(xs, ys, marker="o", color=f"C{i}", label=sc)
        h = result["headlines"].get(sc, {}).get("error_vs_photons")
        if h:
            # The fitted model err^2 = a/N + floor^2, a from the floor crossing.
            b = h["floor_rel_rmse"] ** 2
            a = b * h["floor_reached_at_photons"] if math.isfinite(h["floor_reached_at_photons"]) else None
            if a:
                n = np.geomspace(xs[0], xs[-1], 50)
                ax.loglog(n, np.sqrt(a / n + b), color=f"C{i}", ls=":", lw=1)
            ax.axhline(max(h["floor_rel_rmse"], 1e-5), color=f"C{i}", ls="--", lw=0.7)
    n = np.geomspace(1e4, 1e6, 2)
    ax.loglog(n, 0.3 * (n / 1e4) ** -0.5, color="k", lw=1, label="slope -1/2")
    ax.set_xlabel("photons")
    ax.set_ylabel("relative RMSE (baked texels)")
    ax.set_title("photon lightmaps: error against photons (dashed: fitted floor)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, out / "error_vs_photons.png", files)


def error_maps(result, images, out, files):
    pts = result["points"]
    for info in result["scenes"]:
        sc = info["scene"]
        im = images[sc]
        ref = im["ref_bake"]
        mask = im["mask"]
        scale = np.percentile(ref[mask], 99) if mask.any() else 1.0
        d = next((p for p in pts if p["scene"] == sc and p["method"] == "ours_bake"
                  and p["knob"] == im["ours_default"][0]), None)
        t_ours = d["seconds"] if d else 1.0
        cyc = im.get("cycles_bake", {})
        spp_eq = min(cyc, key=lambda s: abs(math.log(cyc[s][0] / t_ours))) if cyc else None

        def err(x):
            e = np.abs(x - ref).mean(axis=-1) / max(ref[mask].mean(), 1e-12)
            return np.where(mask, e, np.nan)

        rend = im.get("ours_render", {})
        key = max((k for k in rend if k[1] == "ours_render_bilinear"), default=None)
        crend = im.get("cycles_render", {})
        rref = im["ref_render"]
        rscale = np.percentile(rref, 99)
        tiles = [("reference bake (Cycles)", _srgb(_mosaic(ref) / scale), None),
                 (f"ours {im['ours_default'][0] / 1e6:g}M photons, {t_ours:.1f} s",
                  _srgb(_mosaic(im['ours_default'][1]) / scale), None),
                 ("|error| ours", _mosaic(err(im["ours_default"][1])), "err")]
        if "pm_default" in im:
            tiles.append((f"|error| photon map {im['pm_default'][0] / 1e6:g}M", _mosaic(err(im["pm_default"][1])), "err"))
        if spp_eq is not None:
            tiles.append((f"|error| Cycles {spp_eq} spp, {cyc[spp_eq][0]:.1f} s", _mosaic(err(cyc[spp_eq][1])), "err"))
        row2 = [("reference render", _srgb(rref / rscale), None)]
        if key:
            t_r, img = rend[key]
            row2 += [(f"ours render {key[0] / 1e6:g}M, {t_r:.1f} s", _srgb(img / rscale), None),
                     ("|error| ours render", np.abs(img - rref).mean(-1) / rref.mean(), "err")]
            if crend:
                s_eq = min(crend, key=lambda s: abs(math.log(crend[s][0] / t_r)))
                row2 += [(f"Cycles {s_eq} spp, {crend[s_eq][0]:.1f} s", _srgb(crend[s_eq][1] / rscale), None),
                         ("|error| Cycles render", np.abs(crend[s_eq][1] - rref).mean(-1) / rref.mean(), "err")]
        fig = plt.figure(figsize=(13, 5.6))
        gs = fig.add_gridspec(2 + len(tiles), len(row2), height_ratios=[3] + [1] * len(tiles) + [0.15])
        for j, (title, a, kind) in enumerate(row2):
            ax = fig.add_subplot(gs[0, j])
            ax.imshow(a, cmap="magma", vmin=0, vmax=0.5) if kind else ax.imshow(a)
            ax.set_title(title, fontsize=8)
            ax.axis("off")
        for i, (title, a, kind) in enumerate(tiles):
            ax = fig.add_subplot(gs[1 + i, :])
            ax.imshow(a, cmap="magma", vmin=0, vmax=0.5, interpolation="nearest") if kind else \
                ax.imshow(a, interpolation="nearest")
            ax.set_title(title + ("" if i else "   (objects: " + ", ".join(im["names"]) + ")"), fontsize=7)
            ax.axis("off")
        fig.suptitle(f"{sc}: error maps (|error| / mean, colour scale 0..0.5)", fontsize=9)
        fig.subplots_adjust(left=0.01, right=0.99, top=0.93, bottom=0.01, hspace=0.35, wspace=0.05)
        _save(fig, out / f"{sc}_error_map.png", files, dpi=58)


def failure_cases(result, images, out, files):
    pts = result["points"]
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    ax = axes[0, 0]
    for i, info in enumerate(result["scenes"]):
        c = sorted((p for p in pts if p["scene"] == info["scene"] and p["method"] == "ours_bake"),
                   key=lambda p: p["knob"])
        if c:
            ax.loglog([p["photons_per_texel"] for p in c], [max(p["rel_rmse"], 1e-5) for p in c],
                      marker="o", color=f"C{i}", label=info["scene"])
    ax.set_xlabel("recorded photons per texel (mean)")
    ax.set_ylabel("relative RMSE")
    ax.set_title("variance: too few photons per texel", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)

    ax = axes[0, 1]
    fine = [p for p in pts if p["kind"] == "fine"]
    for m in ("ours_floor_constant", "ours_floor_bilinear"):
        c = sorted((p for p in fine if p["method"] == m), key=lambda p: p["knob"])
        if c:
            ax.loglog([p["knob"] for p in c], [max(p["rel_rmse"], 1e-5) for p in c], **STYLE[m])
            ax.loglog([p["knob"] for p in c], [max(abs(p["mean_error"]), 1e-5) for p in c],
                      color=STYLE[m]["color"], ls=":", lw=1)
    ax.set_xlabel("lightmap texels per side (window floor)")
    ax.set_ylabel("relative RMSE (dotted: |mean error|)")
    ax.set_title("bias: texels too coarse for the sun's shadow edge", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    if fine:
        ax.legend(fontsize=7)

    # Undersampled lightmap next to the reference, first scene's first objects.
    ax = axes[1, 0]
    sc = result["scenes"][0]["scene"]
    im = images[sc]
    if "ours_low" in im:
        ref = im["ref_bake"]
        scale = np.percentile(ref[im["mask"]], 99)
        sel = slice(0, min(3, ref.shape[0]))
        a = np.concatenate([_mosaic(ref[sel]), _mosaic(im["ours_low"][1][sel])], axis=0)
        ax.imshow(_srgb(a / scale), interpolation="nearest")
        ax.set_title(f"{sc} {', '.join(im['names'][sel])}: reference (top), "
                     f"{im['ours_low'][0]:,} photons (bottom)", fontsize=8)
    ax.axis("off")

    ax = axes[1, 1]
    fimg = next((images[s]["fine"] for s in images if "fine" in images[s]), None)
    if fimg:
        ref = fimg["reference"]
        scale = np.percentile(ref[fimg["inside"]], 99.5)
        res_list = sorted({k[0] for k in fimg if isinstance(k, tuple)})
        r = res_list[0]
        a = np.concatenate([ref[::-1], fimg[(r, "constant")][::-1], fimg[(r, "bilinear")][::-1]], axis=1)
        ax.imshow(_srgb(a / scale), interpolation="nearest")
        ax.set_title(f"window floor atlas: reference | {r}x{r} constant | {r}x{r} bilinear", fontsize=8)
    ax.axis("off")
    fig.tight_layout()
    _save(fig, out / "failure_cases.png", files)


def make_all(result, images, out):
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    error_vs_time(result, out, files)
    memory_vs_error(result, out, files)
    error_vs_photons(result, out, files)
    error_maps(result, images, out, files)
    failure_cases(result, images, out, files)
    return files


# --------------------------------------------------------------------------------------
# bench_csg: exact CSG against the tessellated Boolean mesh, split against plain lightmaps
# --------------------------------------------------------------------------------------

def _model_colour(m):
    return {"exact": "C0", "exact_plain": "C1"}.get(m, f"C{2 + abs(hash(m)) % 5}")


def csg_charts(result, images, out):
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    pts = result["points"]
    scenes = [i["scene"] for i in result["scenes"]]
    models = [m for m in dict.fromkeys(p["model"] for p in pts) if m != "exact_plain"]
    tess = sorted({p["model"] for p in pts if p["model"].startswith("tess")},
                  key=lambda m: int(m[4:]))
    colours = {"exact": "C0", **{m: f"C{2 + i}" for i, m in enumerate(tess)}}

    # 1. exact against tessellated: five quantities, log bars per scene
    panels = (("primitives + triangles", lambda p: p["primitives"] + p["triangles"]),
              ("memory: trace buffer + lightmaps (MiB)", lambda p: p["memory_bytes"] / 2 ** 20),
              ("setup s: Boolean + unwrap + export + compile", lambda p: p["setup_seconds"]),
              ("photon pass s", lambda p: p["photon_seconds"]),
              ("render relative RMSE vs Cycles", lambda p: max(p["rel_rmse"], 1e-4)))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.3 * len(panels), 3.6))
    width = 0.8 / max(len(models), 1)
    x = np.arange(len(scenes))
    for ax, (title, f) in zip(axes, panels):
        for k, m in enumerate(models):
            vals = [next((f(p) for p in pts if p["scene"] == s and p["model"] == m), np.nan) for s in scenes]
            ax.bar(x + (k - (len(models) - 1) / 2) * width, vals, width, color=colours.get(m, "C7"),
                   label="exact CSG" if m == "exact" else f"Boolean mesh, {m[4:]} segments")
        ax.set_yscale("log")
        ax.set_xticks(x)
        ax.set_xticklabels([s.replace("fig55_", "5.5 ") for s in scenes], rotation=30, fontsize=7)
        ax.set_title(title, fontsize=8)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].legend(fontsize=6)
    fig.suptitle("exact CSG against Blender's Exact-Boolean mesh (this engine, same photons)", fontsize=9)
    fig.tight_layout()
    _save(fig, out / "csg_exact_vs_tessellated.png", files)

    # 2. split (CSG-aware) against plain lightmaps
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    sp = [i["split"] for i in result["scenes"]]
    ax = axes[0]
    ax.bar(x - 0.2, [100 * s["photon_overhead"] for s in sp], 0.4, color="C0", label="photon-pass time")
    ax.bar(x + 0.2, [100 * s["lightmap_memory_overhead"] for s in sp], 0.4, color="C1",
           label="lightmap memory")
    ax.axhline(10.0, color="k", ls="--", lw=1, label="goal: 10 %")
    ax.axhline(0.0, color="0.5", lw=0.7)
    ax.set_ylabel("overhead of split lightmaps (%)")
    ax.set_title("CSG-aware lightmaps against plain ones", fontsize=9)
    ax.set_xticks(x)
    ax.set_xticklabels([s.replace("fig55_", "5.5 ") for s in scenes], rotation=30, fontsize=7)
    ax.legend(fontsize=7)
    ax = axes[1]
    ax.bar(x - 0.2, [s["rel_rmse_split"] for s in sp], 0.4, color="C0", label="split (visible texel area)")
    ax.bar(x + 0.2, [s["rel_rmse_plain"] for s in sp], 0.4, color="C1", label="plain (full texel area)")
    ax.set_ylabel("render relative RMSE vs Cycles")
    ax.set_xticks(x)
    ax.set_xticklabels([s.replace("fig55_", "5.5 ") for s in scenes], rotation=30, fontsize=7)
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, out / "csg_split_overhead.png", files)

    # 3. images: reference, exact, plain, coarsest Boolean mesh and |error| maps
    cols = ["reference", "exact", "exact_plain"] + tess[:1]
    fig, axes = plt.subplots(len(scenes), 2 * len(cols) - 1, figsize=(2.0 * (2 * len(cols) - 1),
                                                                       2.1 * len(scenes)), squeeze=False)
    for r, s in enumerate(scenes):
        im = images[s]
        ref = im["reference"]
        scale = np.percentile(ref, 99)
        j = 0
        for c in cols:
            if c not in im:
                continue
            axes[r, j].imshow(_srgb(im[c] / scale))
            axes[r, j].set_title(f"{s.replace('fig55_', '5.5 ')}: {c}", fontsize=7)
            j += 1
            if c != "reference":
                axes[r, j].imshow(np.abs(im[c] - ref).mean(-1) / ref.mean(), cmap="magma", vmin=0, vmax=0.5)
                axes[r, j].set_title(f"|error| {c}", fontsize=7)
                j += 1
        for a in axes[r]:
            a.axis("off")
    fig.suptitle("renders against Cycles on the finest Boolean mesh (|error| / mean, 0..0.5)", fontsize=9)
    fig.tight_layout()
    _save(fig, out / "csg_images.png", files, dpi=58)
    return files
