"""Writes engine/shading/data/cie_1931_2deg.npz from colour-science's data.

The spectral mode (engine/shading/spectrum.py) needs the CIE 1931 2-degree
colour matching functions and the D65 illuminant. They are published tables;
this script takes them from colour-science (the CIE's own files, as that
package ships them) at 1 nm from 360 to 830 nm, so nothing is typed by hand and
the add-on does not need colour-science at run time.

    .venv/bin/python scripts/make_spectral_data.py
"""
import pathlib

import numpy as np

OUT = pathlib.Path(__file__).resolve().parents[1] / "engine" / "shading" / "data" / "cie_1931_2deg.npz"


def main():
    import colour
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = np.arange(360, 831, dtype=np.float64)
    xyz = cmfs.copy().align(colour.SpectralShape(360, 830, 1)).values
    # D65 is tabulated at 5 nm from 300 nm; colour-science interpolates it to 1 nm
    # (Sprague), as CIE 15 recommends
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(colour.SpectralShape(360, 830, 1)).values
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, wavelength=wl, xyz=xyz, d65=d65,
                        source=np.array(f"colour-science {colour.__version__}: "
                                        "MSDS_CMFS['CIE 1931 2 Degree Standard Observer'], "
                                        "SDS_ILLUMINANTS['D65'], 360-830 nm at 1 nm"))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
