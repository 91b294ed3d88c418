"""The NAO (its legs and cameras, the paper's model) as a robot kind: naocal.dataset/1-2 directories (or a
`naocal calibrate --out` run holding one), naocal.offsets/1-2 files and the simulator's naocal.truth files. The
bodies live in kinds/nao/<verb>.py, its options in kinds/nao/options.py."""

from __future__ import annotations

import argparse
from pathlib import Path

from naocal.kinds.nao import options


def _schema(path: Path):
    """The "schema" of the JSON file `path`, None if it is not a readable JSON object."""
    from naocal.solver.errors import DataError
    from naocal.solver.fileio import read_json

    try:  # read_json: regular files only (a FIFO must not block the check), size capped
        doc = read_json(path)
    except DataError:
        return None
    return doc.get("schema") if isinstance(doc, dict) else None


class NaoKind:
    name = "nao"

    def claims(self, source) -> bool:
        if isinstance(source, argparse.Namespace):  # no option is the NAO's alone: it is the default kind
            return False
        from naocal.solver.dataset import SCHEMAS as DATASET_SCHEMAS
        from naocal.solver.offsets import SCHEMA_V1, SCHEMA_V2, TRUTH_SCHEMAS

        path = Path(source)
        if path.is_dir():  # a dataset, or a `naocal calibrate --out` run holding one
            return any(_schema(d / "dataset.json") in DATASET_SCHEMAS for d in (path, path / "dataset"))
        return _schema(path) in (SCHEMA_V1, SCHEMA_V2, *TRUTH_SCHEMAS)

    def add_options(self, parser, verb: str) -> None:
        options.add_options(parser, verb)

    def identify(self, args) -> int:
        from naocal.kinds.nao.identify import run

        return run(args)

    def diagnose(self, args) -> int:
        from naocal.kinds.nao.diagnose import run

        return run(args)

    def verify(self, args) -> int:
        from naocal.kinds.nao.verify import run

        return run(args)

    def simulate(self, args) -> int:
        from naocal.kinds.nao.simulate import run

        return run(args)

    def offsets(self, args, action: str, out) -> int:
        from naocal.kinds.nao import offsets

        return {"show": offsets.run_show, "diff": offsets.run_diff, "validate": offsets.run_validate,
                "export": offsets.run_export, "apply": offsets.run_apply}[action](args, out)

    def diagnosis_report(self, dataset_path, report_dir) -> str:
        """`naocal diagnose DATASET --report DIR`'s report with its defaults (for `naocal calibrate --report`)."""
        from naocal.kinds.nao.diagnose import diagnose_dataset, write_diagnosis_report

        dataset, _, diagnosis = diagnose_dataset(dataset_path)
        return write_diagnosis_report(report_dir, diagnosis, dataset, dataset_path)


KIND = NaoKind()
