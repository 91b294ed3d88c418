"""`naocal import FORMAT DIR --out DATASET`: turn data recorded elsewhere into a naocal.dataset/2.

    naocal import mrlspl DIR --out DATASET

mrlspl: MRL-SPL's 2009 calibration samples of a standing NAO V3 looking at a 4 x 4 board on the floor
(tests/data/realdata/mrlspl-nao-2009/: joints_raw.csv and image_<N>.png; tools/import_mrlspl.py says what is
done to them). The board's corners are found by naocal's detector and put in the `floor` target's vertex order
by the nominal model's prediction; each image gets the gravity of a flat right sole; the camera is the 320 x 240
bottom camera with the nominal field of view (fx = fy = 271.8 px). dataset.json records all of it
(`source`, `provenance`), and the images are copied into DATASET/images/.

DATASET must not exist or be an empty directory. Exit codes: 0 written, 2 bad input (one line naming the file,
line and field; nothing is written).
"""

import argparse

FORMATS = ("mrlspl",)


def register(subparsers):
    p = subparsers.add_parser(
        "import", help="turn data recorded elsewhere (mrlspl: MRL-SPL's 2009 NAO samples) into a dataset",
        description=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("format", choices=FORMATS, help="the data's origin")
    p.add_argument("directory", metavar="DIR", help="the directory holding the data")
    p.add_argument("--out", required=True, metavar="DATASET", help="the dataset directory to create")
    p.set_defaults(run=run)


def run(args) -> int:
    import numpy as np

    from naocal.tools.import_mrlspl import import_mrlspl

    dataset = import_mrlspl(args.directory, args.out)
    per_image = dataset.meta["provenance"]["images"]
    for image, how in per_image.items():
        print(f"image {image}: {how['channel']}, line fit {how['line_rms_px']:.2f} px, order: {how['order']}, "
              f"nominal model {how['nominal_rms_px']:.1f} px off")
    r = np.array([how["nominal_rms_px"] for how in per_image.values()])
    print(f"naocal import: wrote {args.out}: {len(per_image)} images, {dataset.n_rows} corners "
          f"(nominal model RMS {np.sqrt(np.mean(r ** 2)):.1f} px)")
    return 0
