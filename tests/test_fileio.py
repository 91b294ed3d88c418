"""Writers on a full disk: one DiskFullError naming the file and the free bytes; what was saved stays intact."""

import errno
import os
import signal
import stat

import numpy as np
import pytest

from naocal.solver.dataset import DatasetAppender, read_dataset
from naocal.solver.errors import DiskFullError, NaocalError
from naocal.solver.fileio import atomic_write_bytes, atomic_write_text
from naocal.sim.synthetic import dataset_parts, random_truth, synthesize


def failing(real, code=errno.ENOSPC):
    def call(*args, **kwargs):
        raise OSError(code, os.strerror(code))

    return call


@pytest.mark.parametrize("target, code, words", [
    ("fsync", errno.ENOSPC, "no space left"),
    ("fsync", errno.EDQUOT, "quota"),
    ("link", errno.ENOSPC, "no space left"),  # the .bak hard link
])
def test_atomic_write_on_a_full_disk_names_the_file_and_keeps_the_old_one(tmp_path, monkeypatch, target, code, words):
    path = tmp_path / "offsets.json"
    atomic_write_text(path, "old\n")
    atomic_write_text(path, "older\n", backup_suffix=".bak")  # so that .bak exists too
    monkeypatch.setattr(os, target, failing(getattr(os, target), code))
    with pytest.raises(DiskFullError) as info:
        atomic_write_text(path, "new\n", backup_suffix=".bak")
    monkeypatch.undo()
    err = info.value
    assert isinstance(err, NaocalError) and err.exit_code == 3
    assert str(path) in str(err) and words in str(err) and "bytes free" in str(err)
    assert err.free_bytes is not None and err.free_bytes > 0
    assert len(str(err).splitlines()) == 1
    assert path.read_text() == "older\n" and (tmp_path / "offsets.json.bak").read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["offsets.json", "offsets.json.bak"]  # no temporary left


def test_other_os_errors_stay_what_they_are(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "fsync", failing(os.fsync, errno.EIO))
    with pytest.raises(OSError) as info:
        atomic_write_bytes(tmp_path / "x", b"1")
    assert not isinstance(info.value, DiskFullError) and info.value.errno == errno.EIO


def test_a_capture_appended_to_a_full_disk_leaves_the_dataset_as_it_was(tmp_path, monkeypatch):
    rng = np.random.default_rng(4)
    meta, columns = dataset_parts(synthesize(rng, random_truth(rng), pixel_noise_px=0.1))
    images = np.asarray(columns["image"])
    first, second = (np.flatnonzero(images == i) for i in np.unique(images)[:2])
    appender = DatasetAppender(tmp_path / "ds", meta)
    appender.append({k: np.asarray(v)[first] for k, v in columns.items()})
    before = (tmp_path / "ds" / "observations.csv").read_bytes()

    real_write = os.write

    def half_then_full(fd, data):  # the disk fills in the middle of the capture
        if len(data) > 100:
            real_write(fd, bytes(data[:len(data) // 2]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", half_then_full)
    with pytest.raises(DiskFullError) as info:
        appender.append({k: np.asarray(v)[second] for k, v in columns.items()})
    monkeypatch.undo()
    assert "observations.csv" in str(info.value) and "bytes free" in str(info.value)
    assert (tmp_path / "ds" / "observations.csv").read_bytes() == before
    assert len(np.unique(read_dataset(tmp_path / "ds").columns["image"])) == 1


def test_atomic_write_gives_a_new_file_the_umask_mode_and_keeps_a_replaced_files_mode(tmp_path):
    """mkstemp makes 0600 files: offsets.json or a report written so could not be read by the team's framework."""
    old_umask = os.umask(0o022)
    try:
        fresh = atomic_write_text(tmp_path / "offsets.json", "{}\n")
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o644
        kept = tmp_path / "shared.json"
        kept.write_text("old\n")
        kept.chmod(0o664)
        atomic_write_text(kept, "new\n", backup_suffix=".bak")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o664
        secret = atomic_write_text(tmp_path / "bridge.token", "t\n", mode=0o600)
        assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    finally:
        os.umask(old_umask)


def test_ctrl_c_while_a_capture_is_written_counts_the_capture_it_left_on_disk(tmp_path, monkeypatch):
    """Ctrl-C between the write and the bookkeeping left the summary one image short (a flaky run test)."""
    rng = np.random.default_rng(5)
    meta, columns = dataset_parts(synthesize(rng, random_truth(rng), pixel_noise_px=0.1))
    images = np.asarray(columns["image"])
    image = int(np.unique(images)[0])
    appender = DatasetAppender(tmp_path / "ds", meta)
    real_fsync = os.fsync

    def fsync_then_ctrl_c(fd):
        real_fsync(fd)
        os.kill(os.getpid(), signal.SIGINT)  # arrives once the capture is on disk

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # `pytest &` would ignore SIGINT
    try:
        monkeypatch.setattr(os, "fsync", fsync_then_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            appender.append({k: np.asarray(v)[images == image] for k, v in columns.items()})
        monkeypatch.undo()
    finally:
        signal.signal(signal.SIGINT, previous)
    on_disk = set(int(i) for i in read_dataset(tmp_path / "ds").columns["image"])
    assert on_disk == {image} and appender.captured_images() == on_disk
