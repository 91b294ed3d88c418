"""naocal.dataset/1: round trips, every bad input named by file/line/column, and the crash-safe appender."""

import json
import os

import numpy as np
import pytest

from naocal.solver.dataset import (
    COMMANDED_COLUMNS, FLOAT_COLUMNS, META_FILE, OBSERVATIONS_FILE, REQUIRED_COLUMNS,
    ROWS_IN_IMAGE_COLUMN, SCHEMA, VELOCITY_COLUMNS, Dataset, DatasetAppender, format_rows, read_dataset,
    write_dataset,
)
from naocal.solver.errors import DataError
from naocal.solver.joints import JOINTS
from naocal.solver.limits import joint_limits


def make_meta(**changes):
    meta = {
        "schema": SCHEMA,
        "robot": {"id": "nao-17", "model": "H25 V6"},
        "camera": {"name": "bottom", "width_px": 640, "height_px": 480, "fx_px": 608.5, "fy_px": 609.25,
                   "cx_px": 320.1, "cy_px": 239.7, "distortion": [0.01, -0.02, 0.0, 0.0, 0.0]},
        "board": {"columns": 7, "rows": 5, "square_m": 0.025, "center_x_m": 0.17, "mass_kg": 0.1},
        "source": "synthetic test data",
    }
    meta.update(changes)
    return meta


def make_columns(n_images=6, n_vertices=24, seed=0, velocities=False):
    """Random but valid columns: per-image values repeated on every row of the image."""
    rng = np.random.default_rng(seed)
    image = np.repeat(np.arange(n_images), n_vertices)
    per_image = lambda values: np.asarray(values)[image]  # noqa: E731
    columns = {
        "image": image,
        "leg": per_image(np.where(np.arange(n_images) % 2 == 0, "L", "R")),
        "stance": per_image(np.arange(n_images) // 2),
        "head_posture": per_image(np.arange(n_images) % 3),
        "vertex": np.tile(np.arange(n_vertices), n_images),
    }
    for name in FLOAT_COLUMNS:
        columns[name] = rng.normal(size=image.size) * 0.1
    columns["t_image_s"] = per_image(np.arange(n_images) * 2.0 + rng.random(n_images))
    lower, upper = np.array([joint_limits()[j] for j in JOINTS]).T
    for prefix in ("", "cmd_"):
        angles = rng.uniform(lower, upper, size=(n_images, 14))  # the reader refuses angles far beyond the limits
        for j, joint in enumerate(JOINTS):
            columns[prefix + joint] = angles[image, j]
    directions = rng.integers(-1, 2, size=(n_images, 14)).astype(float)
    for j, joint in enumerate(JOINTS):
        columns["dir_" + joint] = directions[image, j]
    if velocities:
        for j, joint in enumerate(JOINTS):
            columns["vel_" + joint] = per_image(rng.normal(size=n_images) * 1e-3)
    columns["detector_score"] = rng.random(image.size)
    columns["note"] = np.array([f"cap{i}" for i in image])
    return columns


@pytest.fixture
def dataset_dir(tmp_path):
    path = tmp_path / "ds"
    write_dataset((make_meta(), make_columns()), path)
    return path


def assert_same_dataset(a: Dataset, b: Dataset):
    assert a.meta == b.meta
    assert list(a.columns) == list(b.columns)
    for name in a.columns:
        x, y = a.columns[name], b.columns[name]
        assert x.dtype == y.dtype, name
        if x.dtype.kind == "f":
            assert np.array_equal(x.view(np.uint64), y.view(np.uint64)), name  # bit-identical
        else:
            assert np.array_equal(x, y), name


# ------------------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("velocities", [False, True])
def test_write_read_round_trip_is_bit_identical(tmp_path, velocities):
    columns = make_columns(velocities=velocities)
    columns["x_sole_m"][3] = -0.0  # the sign of zero survives too
    written = write_dataset({"meta": make_meta(), "columns": columns}, tmp_path / "a")
    read = read_dataset(tmp_path / "a")
    assert_same_dataset(written, read)
    for name, values in columns.items():
        if np.asarray(values).dtype.kind == "f":
            assert np.array_equal(np.asarray(values, dtype=float).view(np.uint64),
                                  read.columns[name].view(np.uint64)), name
    write_dataset(read, tmp_path / "b")
    assert (tmp_path / "a" / OBSERVATIONS_FILE).read_bytes() == (tmp_path / "b" / OBSERVATIONS_FILE).read_bytes()
    assert_same_dataset(read, read_dataset(tmp_path / "b"))


def test_types_defaults_and_helpers(dataset_dir):
    ds = read_dataset(dataset_dir)
    assert ds.meta["gravity_torso_mps2"] == [-9.81, 0.0, 0.0]
    for name in ("image", "stance", "head_posture", "vertex"):
        assert ds.columns[name].dtype == np.int64
    assert ds.columns["leg"].dtype.kind == "U" and set(ds.columns["leg"]) == {"L", "R"}
    assert ds.columns["u_px"].dtype == np.float64
    assert ds.columns["detector_score"].dtype == np.float64  # numeric extra column
    assert ds.columns["note"].dtype.kind == "U"  # text extra column
    assert ds.n_rows == 6 * 24
    assert list(ds.images()) == list(range(6))
    measured = ds.joint_matrix()
    assert measured.shape == (ds.n_rows, 14)
    assert np.array_equal(measured[:, JOINTS.index("LKneePitch")], ds.columns["LKneePitch"])
    assert np.array_equal(ds.joint_matrix("cmd_")[:, 0], ds.columns[COMMANDED_COLUMNS[0]])
    assert set(np.unique(ds.joint_matrix("dir_"))) <= {-1.0, 0.0, 1.0}
    assert not ds.has_velocities
    with pytest.raises(KeyError):
        ds.joint_matrix("vel_")
    subset = ds.select(ds.columns["leg"] == "L")
    assert set(subset.columns["leg"]) == {"L"} and subset.n_rows == 3 * 24


def test_written_columns_are_in_issue_order_then_extras(tmp_path):
    columns = make_columns(velocities=True)
    shuffled = dict(reversed(list(columns.items())))
    write_dataset((make_meta(), shuffled), tmp_path / "d")
    header = (tmp_path / "d" / OBSERVATIONS_FILE).read_text().splitlines()[0].split(",")
    n = len(REQUIRED_COLUMNS)
    assert header[:n] == list(REQUIRED_COLUMNS)
    assert header[n:n + 14] == list(VELOCITY_COLUMNS)
    assert header[n + 14:] == ["note", "detector_score"]  # extras keep their given order


def test_reads_columns_in_any_order_and_optional_images_dir(dataset_dir):
    lines = (dataset_dir / OBSERVATIONS_FILE).read_text().splitlines()
    table = [line.split(",") for line in lines]
    permuted = [list(reversed(row)) for row in table]
    (dataset_dir / OBSERVATIONS_FILE).write_text("\r\n".join(",".join(r) for r in permuted) + "\r\n")
    (dataset_dir / "images").mkdir()
    (dataset_dir / "images" / "000000.png").write_bytes(b"not read")
    ds = read_dataset(dataset_dir)
    assert ds.n_rows == 6 * 24 and list(ds.columns)[0] == "note"


def test_quoted_csv_is_read_with_the_csv_module(tmp_path):
    columns = make_columns()
    columns["note"] = np.array(['a "quoted", text'] * len(columns["image"]))
    write_dataset((make_meta(), columns), tmp_path / "q")
    assert read_dataset(tmp_path / "q").columns["note"][0] == 'a "quoted", text'


# ----------------------------------------------------------------------------------------- bad inputs


def rewrite_cell(path, line, column, value):
    """Set one CSV cell (line is 1-based, the header is line 1)."""
    obs = path / OBSERVATIONS_FILE
    lines = obs.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    obs.write_text("\n".join(lines) + "\n")


def expect_error(path, *fragments):
    with pytest.raises(DataError) as info:
        read_dataset(path)
    message = str(info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return info.value


@pytest.mark.parametrize("column,value,problem", [
    ("u_px", "abc", "expected a finite number"),
    ("u_px", "", "expected a finite number"),
    ("v_px", "nan", "expected a finite number"),
    ("t_joints_s", "inf", "expected a finite number"),
    ("vertex", "24", "vertex must be in 0..23"),
    ("vertex", "-1", "vertex must be in 0..23"),
    ("vertex", "2.5", "expected a whole number"),
    ("image", "x", "expected a finite number"),
    ("leg", "X", "unknown leg"),
    ("leg", "l", "unknown leg"),
])
def test_bad_values_name_file_line_and_column(dataset_dir, column, value, problem):
    rewrite_cell(dataset_dir, 10, column, value)
    err = expect_error(dataset_dir, "observations.csv", "line 10", f"'{column}'", problem)
    assert err.line == 10 and err.field == column


@pytest.mark.parametrize("column", ["LHipPitch", "cmd_RKneePitch", "HeadYaw", "stance", "head_posture"])
@pytest.mark.parametrize("value", ["0.123", "nan", "oops"])
def test_per_image_values_must_agree_and_be_valid(dataset_dir, column, value):
    rewrite_cell(dataset_dir, 30, column, value)  # line 30 = image 1 (lines 26..49), not its first row
    problem = {"0.123": "differs within image 1", "nan": "expected a finite number",
               "oops": "expected a finite number"}[value]
    if column in ("stance", "head_posture") and value == "0.123":
        problem = "expected a whole number"
    expect_error(dataset_dir, "line 30", f"'{column}'", problem)


def test_leg_must_agree_within_an_image(dataset_dir):
    rewrite_cell(dataset_dir, 30, "leg", "L")  # image 1 is a right-leg image
    expect_error(dataset_dir, "line 30", "'leg'", "differs within image 1")


def test_per_image_values_written_differently_but_equal_are_accepted(dataset_dir):
    lines = (dataset_dir / OBSERVATIONS_FILE).read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[29].split(",")
    value = float(cells[header.index("LHipPitch")])
    rewrite_cell(dataset_dir, 30, "LHipPitch", f"{value:.17e}")
    assert read_dataset(dataset_dir).columns["LHipPitch"][28] == value


def test_direction_must_be_a_sign(dataset_dir):
    for line in range(2, 26):  # all rows of image 0
        rewrite_cell(dataset_dir, line, "dir_LAnklePitch", "0.5")
    expect_error(dataset_dir, "line 2", "dir_LAnklePitch", "-1, 0 or 1")


def test_duplicate_vertex_in_one_image(dataset_dir):
    rewrite_cell(dataset_dir, 12, "vertex", "3")  # image 0 already has vertex 3 on line 5
    expect_error(dataset_dir, "line 12", "duplicate observation of vertex 3 in image 0")


@pytest.mark.parametrize("column", ["u_px", "leg", "dir_HeadYaw", "cmd_LHipYawPitch", "RAnkleRoll", "image"])
def test_missing_column(dataset_dir, column):
    columns = make_columns()
    del columns[column]
    obs = dataset_dir / OBSERVATIONS_FILE
    lines = obs.read_text().splitlines()
    header = lines[0].split(",")
    k = header.index(column)
    obs.write_text("\n".join(",".join(c for i, c in enumerate(line.split(",")) if i != k) for line in lines) + "\n")
    err = expect_error(dataset_dir, "observations.csv", "line 1", f"'{column}'", "missing required column")
    assert err.field == column


def test_partial_velocity_columns_are_refused(tmp_path):
    columns = make_columns(velocities=True)
    del columns["vel_LKneePitch"]
    with pytest.raises(DataError, match="vel_LKneePitch.*all 14 joints or none"):
        write_dataset((make_meta(), columns), tmp_path / "v")
    columns = make_columns(velocities=True)
    columns["vel_HeadYaw"] = columns["vel_HeadYaw"].copy()
    columns["vel_HeadYaw"][:24] = np.nan
    with pytest.raises(DataError, match="line 2.*vel_HeadYaw.*expected a finite number"):
        write_dataset((make_meta(), columns), tmp_path / "v")
    assert not (tmp_path / "v" / OBSERVATIONS_FILE).exists()  # nothing written on failure


@pytest.mark.parametrize("content,problem", [
    ("", "empty file"),
    ("\n\n", "empty file"),
    (None, "no observations"),  # header only
])
def test_empty_observations(dataset_dir, content, problem):
    obs = dataset_dir / OBSERVATIONS_FILE
    if content is None:
        content = obs.read_text().splitlines()[0] + "\n"
    obs.write_text(content)
    expect_error(dataset_dir, "observations.csv", problem)


def test_wrong_number_of_fields(dataset_dir):
    obs = dataset_dir / OBSERVATIONS_FILE
    lines = obs.read_text().splitlines()
    lines[7] = lines[7].rsplit(",", 3)[0]  # a row cut short, e.g. by a crash
    obs.write_text("\n".join(lines) + "\n")
    expect_error(dataset_dir, "line 8", "fields, but the header has")


def test_missing_files(dataset_dir, tmp_path):
    expect_error(tmp_path / "nope", "nope", "not found")
    (dataset_dir / OBSERVATIONS_FILE).unlink()
    expect_error(dataset_dir, "observations.csv", "file not found")
    (dataset_dir / META_FILE).unlink()
    expect_error(dataset_dir, "dataset.json", "file not found")


@pytest.mark.parametrize("cut", [1, 10, 200, -3])
def test_truncated_json(dataset_dir, cut):
    meta_path = dataset_dir / META_FILE
    text = meta_path.read_text()
    meta_path.write_text(text[:cut] if cut > 0 else text[:cut - 1])
    err = expect_error(dataset_dir, "dataset.json", "truncated JSON", "line ")
    assert err.line is not None


def test_invalid_json_names_position(dataset_dir):
    meta_path = dataset_dir / META_FILE
    meta_path.write_text('{\n  "schema": "naocal.dataset/1",\n  "robot": {,}\n}\n')
    expect_error(dataset_dir, "dataset.json", "line 3", "invalid JSON")


def meta_variants():
    def drop(*keys):
        def change(meta):
            target = meta
            for key in keys[:-1]:
                target = target[key]
            del target[keys[-1]]
        return change

    def setter(value, *keys):
        def change(meta):
            target = meta
            for key in keys[:-1]:
                target = target[key]
            target[keys[-1]] = value
        return change

    return [
        (setter("naocal.dataset/3", "schema"), "schema", "wrong schema"),
        (drop("schema"), "schema", "missing required field"),
        (drop("camera", "fx_px"), "camera.fx_px", "missing required field"),
        (drop("board"), "board", "missing required field"),
        (drop("robot", "id"), "robot.id", "missing required field"),
        (setter(float("nan"), "camera", "cx_px"), "camera.cx_px", "non-finite"),
        (setter(float("inf"), "pixel_noise_px"), "pixel_noise_px", "non-finite"),
        (setter("600", "camera", "fy_px"), "camera.fy_px", "expected a finite number"),
        (setter(-600.0, "camera", "fy_px"), "camera.fy_px", "must be positive"),
        (setter(640.5, "camera", "width_px"), "camera.width_px", "expected a whole number"),
        (setter(True, "board", "columns"), "board.columns", "expected a finite number"),
        (setter([0.0, 1.0], "gravity_torso_mps2"), "gravity_torso_mps2", "list of 3"),
        (setter([0.0] * 4, "camera", "distortion"), "camera.distortion", "list of 5"),
        (setter("top", "camera", "name"), "camera.name", "not supported"),
        (setter(7, "source"), "source", "expected text"),
        (setter([], "robot"), "robot", "JSON object"),
    ]


@pytest.mark.parametrize("change,field,problem", meta_variants())
def test_bad_meta_names_the_field(dataset_dir, change, field, problem):
    meta = json.loads((dataset_dir / META_FILE).read_text())
    change(meta)
    (dataset_dir / META_FILE).write_text(json.dumps(meta))  # json writes NaN as NaN: the reader must refuse it
    err = expect_error(dataset_dir, "dataset.json", f"'{field}'", problem)
    assert err.field == field


def test_board_size_defines_the_vertex_range(tmp_path):
    columns = make_columns(n_vertices=4)
    meta = make_meta(board={"columns": 3, "rows": 3, "square_m": 0.03, "center_x_m": 0.17, "mass_kg": 0.1})
    write_dataset((meta, columns), tmp_path / "small")
    rewrite_cell(tmp_path / "small", 3, "vertex", "4")
    expect_error(tmp_path / "small", "vertex must be in 0..3")


def test_writer_refuses_bad_data_and_writes_nothing(tmp_path):
    columns = make_columns()
    columns["u_px"] = columns["u_px"].copy()
    columns["u_px"][5] = np.inf
    with pytest.raises(DataError, match="line 7.*u_px.*expected a finite number"):
        write_dataset((make_meta(), columns), tmp_path / "w")
    assert not (tmp_path / "w").exists() or not any((tmp_path / "w").iterdir())


def test_writer_replaces_atomically_and_keeps_no_temporaries(dataset_dir):
    before = sorted(p.name for p in dataset_dir.iterdir())
    write_dataset((make_meta(source="second"), make_columns(seed=3)), dataset_dir)
    assert sorted(p.name for p in dataset_dir.iterdir()) == before
    assert read_dataset(dataset_dir).meta["source"] == "second"


# ------------------------------------------------------------------------------------------ appender


def capture_rows(columns, image):
    """The rows of one image as a list of dicts, as the agent produces them."""
    mask = np.asarray(columns["image"]) == image
    names = [n for n in columns if n not in ("note", "detector_score")]
    return [{n: np.asarray(columns[n])[i] for n in names} for i in np.flatnonzero(mask)]


def test_appender_builds_a_readable_dataset_and_resumes(tmp_path):
    path = tmp_path / "run"
    columns = make_columns(n_images=4)
    appender = DatasetAppender(path, make_meta())
    assert appender.captured_images() == set() and appender.repair is None
    assert (path / META_FILE).exists() and not (path / OBSERVATIONS_FILE).exists()
    for image in (0, 1):
        assert appender.append(capture_rows(columns, image)) == 24
    assert appender.append([]) == 0
    resumed = DatasetAppender(path, make_meta(source="resumed run"))  # source may differ
    assert resumed.captured_images() == {0, 1} and resumed.repair is None
    with pytest.raises(DataError, match="image 1 is already saved"):
        resumed.append(capture_rows(columns, 1))
    resumed.append(capture_rows(columns, 2))
    ds = read_dataset(path)
    assert list(ds.images()) == [0, 1, 2]
    assert set(ds.columns[ROWS_IN_IMAGE_COLUMN]) == {24.0}
    assert ds.meta["source"] == "synthetic test data"  # the existing dataset.json is kept
    for name in ("u_px", "LHipPitch", "dir_RAnkleRoll"):
        assert np.array_equal(ds.columns[name], columns[name][: 3 * 24])


def test_appender_accepts_a_dict_of_columns(tmp_path):
    columns = make_columns(n_images=2)
    appender = DatasetAppender(tmp_path / "d", make_meta())
    mask = columns["image"] == 1
    appender.append({n: np.asarray(v)[mask] for n, v in columns.items()})
    ds = read_dataset(tmp_path / "d")
    assert list(ds.images()) == [1] and ds.columns["note"][0] == "cap1"


def test_appender_refuses_bad_captures_and_writes_nothing(tmp_path):
    columns = make_columns(n_images=2)
    appender = DatasetAppender(tmp_path / "d", make_meta())
    appender.append(capture_rows(columns, 0))
    size = (tmp_path / "d" / OBSERVATIONS_FILE).stat().st_size
    rows = capture_rows(columns, 1)
    rows[3]["u_px"] = float("nan")
    with pytest.raises(DataError, match="u_px.*expected a finite number"):
        appender.append(rows)
    two_images = capture_rows(columns, 1)
    two_images[0]["image"] = 5
    with pytest.raises(DataError, match="one image"):
        appender.append(two_images)
    extra = capture_rows(columns, 1)
    for row in extra:
        row["new_column"] = 1.0
    with pytest.raises(DataError, match="differ from the file's header"):
        appender.append(extra)
    assert (tmp_path / "d" / OBSERVATIONS_FILE).stat().st_size == size


def test_appender_refuses_an_incompatible_dataset(tmp_path):
    DatasetAppender(tmp_path / "d", make_meta())
    other = make_meta(robot={"id": "nao-99", "model": "H25 V6"})
    with pytest.raises(DataError, match="different 'robot'"):
        DatasetAppender(tmp_path / "d", other)


def test_appender_fsyncs_every_capture_in_one_write(tmp_path, monkeypatch):
    columns = make_columns(n_images=2)
    appender = DatasetAppender(tmp_path / "d", make_meta())
    calls = []
    real_write, real_fsync = os.write, os.fsync
    monkeypatch.setattr(os, "write", lambda fd, data: calls.append(("write", len(data))) or real_write(fd, data))
    monkeypatch.setattr(os, "fsync", lambda fd: calls.append(("fsync",)) or real_fsync(fd))
    appender.append(capture_rows(columns, 0))
    appender.append(capture_rows(columns, 1))
    writes = [c for c in calls if c[0] == "write"]
    assert len(writes) == 2  # one write per capture (the first one carries the header)
    first_fsync = calls.index(("fsync",))
    assert calls[0][0] == "write" and first_fsync == 1  # fsync right after the write
    assert calls.count(("fsync",)) >= 2


def torn_append(path, data: bytes):
    with open(path / OBSERVATIONS_FILE, "ab") as f:
        f.write(data)


@pytest.mark.parametrize("kept_lines", [0, 1, 5, 23])
def test_resume_cuts_a_torn_capture(tmp_path, kept_lines):
    """A crash in the middle of a capture's write leaves a prefix of it: resume drops all of it, nothing else."""
    path = tmp_path / "d"
    columns = make_columns(n_images=3)
    appender = DatasetAppender(path, make_meta())
    appender.append(capture_rows(columns, 0))
    appender.append(capture_rows(columns, 1))
    complete = (path / OBSERVATIONS_FILE).read_bytes()
    # What the third append would have written, cut after `kept_lines` complete lines and half a line.
    header = complete.split(b"\n", 1)[0].decode().split(",")
    rows = capture_rows(columns, 2)
    for row in rows:
        row[ROWS_IN_IMAGE_COLUMN] = 24
    capture_lines = format_rows({n: [r[n] for r in rows] for n in header}, header).encode().splitlines(True)
    assert len(capture_lines) == 24
    torn = b"".join(capture_lines[:kept_lines]) + capture_lines[kept_lines][:17]
    torn_append(path, torn)

    resumed = DatasetAppender(path, make_meta())
    assert resumed.repair is not None and "torn" in resumed.repair
    assert (path / OBSERVATIONS_FILE).read_bytes() == complete
    assert (path / (OBSERVATIONS_FILE + ".torn")).read_bytes().startswith(torn)
    assert resumed.captured_images() == {0, 1}
    resumed.append(capture_rows(columns, 2))
    assert list(read_dataset(path).images()) == [0, 1, 2]


def test_resume_cuts_a_capture_torn_exactly_at_a_line_end(tmp_path):
    path = tmp_path / "d"
    columns = make_columns(n_images=2)
    appender = DatasetAppender(path, make_meta())
    appender.append(capture_rows(columns, 0))
    complete = (path / OBSERVATIONS_FILE).read_bytes()
    appender.append(capture_rows(columns, 1))
    data = (path / OBSERVATIONS_FILE).read_bytes()
    lines = data.splitlines(keepends=True)
    (path / OBSERVATIONS_FILE).write_bytes(b"".join(lines[:-10]))  # 14 of image 1's 24 lines survived
    resumed = DatasetAppender(path, make_meta())
    assert resumed.repair is not None
    assert (path / OBSERVATIONS_FILE).read_bytes() == complete
    assert resumed.captured_images() == {0}


def test_resume_after_a_torn_first_capture_starts_afresh(tmp_path):
    path = tmp_path / "d"
    columns = make_columns(n_images=1)
    DatasetAppender(path, make_meta()).append(capture_rows(columns, 0))
    data = (path / OBSERVATIONS_FILE).read_bytes()
    (path / OBSERVATIONS_FILE).write_bytes(data[: data.index(b"\n") + 40])  # header + part of a row
    resumed = DatasetAppender(path, make_meta())
    assert resumed.repair is not None and resumed.captured_images() == set()
    assert (path / OBSERVATIONS_FILE).read_bytes() == b""
    resumed.append(capture_rows(columns, 0))
    assert read_dataset(path).n_rows == 24


def test_resume_keeps_a_complete_file_from_another_tool(dataset_dir):
    """A dataset without rows_in_image: only a last line without newline counts as torn."""
    obs = dataset_dir / OBSERVATIONS_FILE
    complete = obs.read_bytes()
    obs.write_bytes(complete + b"6,L,0")
    appender = DatasetAppender(dataset_dir, make_meta())
    assert appender.repair is not None
    assert obs.read_bytes() == complete and appender.captured_images() == set(range(6))
    again = DatasetAppender(dataset_dir, make_meta())
    assert again.repair is None and obs.read_bytes() == complete
    more = make_columns(n_images=7)
    mask = more["image"] == 6
    again.append({n: np.asarray(v)[mask] for n, v in more.items()})
    ds = read_dataset(dataset_dir)
    assert list(ds.images()) == list(range(7)) and ROWS_IN_IMAGE_COLUMN not in ds.columns
