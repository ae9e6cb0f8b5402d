"""A dataset with corrupt chunks: named in every error, repaired without losing intact records."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from tactojax.io import (
    CorruptChunkError, CorruptDatasetError, DatasetLockedError, DatasetWriter, dataset_summary, open_dataset,
    repair_dataset,
)

SCHEMA = {"value": {"dtype": "float32", "shape": [3]}, "index": {"dtype": "int64", "shape": []},
          "object_id": {"dtype": "str", "shape": []}}


def record(i: int) -> dict:
    return {"value": np.full(3, i, np.float32), "index": i, "object_id": "a" if i % 2 else "b"}


@pytest.fixture
def damaged(tmp_path):
    """10 records in chunks of 3, 3, 3, 1; chunk 1 truncated, chunk 2 overwritten with garbage."""
    path = tmp_path / "ds"
    with DatasetWriter(path, schema=SCHEMA, metadata={"sensor": "gelslim"}, chunk_size=3) as writer:
        for i in range(10):
            writer.append(record(i))
    truncated, garbage = path / "chunks" / "chunk-000001.npz", path / "chunks" / "chunk-000002.npz"
    truncated.write_bytes(truncated.read_bytes()[:100])
    garbage.write_bytes(np.random.default_rng(0).bytes(garbage.stat().st_size))
    return path


def test_reading_names_every_corrupt_chunk_and_how_to_repair(damaged):
    dataset = open_dataset(damaged)  # the manifest is intact: the dataset opens
    np.testing.assert_array_equal(dataset.read(["index"], indices=[0, 1, 2, 9])["index"], [0, 1, 2, 9])
    with pytest.raises(CorruptChunkError) as caught:
        dataset.read()
    error = caught.value
    assert isinstance(error, CorruptDatasetError) and isinstance(error, ValueError)
    assert [(c.file, c.count, c.first_record) for c in error.chunks] == [
        ("chunks/chunk-000001.npz", 3, 3), ("chunks/chunk-000002.npz", 3, 6)]
    assert all("sha256 mismatch" in c.reason for c in error.chunks)
    message = str(error)
    assert "2 corrupt chunks" in message and "chunk-000001.npz" in message and "chunk-000002.npz" in message
    assert "(records 3-5)" in message and f"tactojax repair {damaged}" in message
    assert "keeping the other 4 of 10 records" in message
    with pytest.raises(CorruptChunkError, match="chunk-000002.npz") as caught:
        dataset_summary(damaged)
    assert len(caught.value.chunks) == 2


def test_repair_keeps_every_intact_record_and_says_what_was_lost(damaged):
    manifest = (damaged / "manifest.json").read_bytes()
    preview = repair_dataset(damaged, dry_run=True)
    assert (damaged / "manifest.json").read_bytes() == manifest  # a dry run changes nothing
    assert preview.lost_records == 6 and preview.kept_records == 4

    report = repair_dataset(damaged)
    assert [c.file for c in report.lost] == ["chunks/chunk-000001.npz", "chunks/chunk-000002.npz"]
    assert report.lost_records == 6 and report.kept_records == 4 and report.kept_chunks == 2
    assert report.moved_to == (damaged / "corrupt" / "chunk-000001.npz", damaged / "corrupt" / "chunk-000002.npz")
    assert all(path.is_file() for path in report.moved_to)  # kept for inspection, not deleted
    json.dumps(report.as_dict())

    dataset = open_dataset(damaged)
    data = dataset.read()
    np.testing.assert_array_equal(data["index"], [0, 1, 2, 9])
    np.testing.assert_array_equal(data["value"][:, 0], [0, 1, 2, 9])
    assert dataset.metadata["sensor"] == "gelslim"
    (repair,) = dataset.metadata["repairs"]
    assert [(lost["file"], lost["records"]) for lost in repair["lost"]] == [
        ("chunks/chunk-000001.npz", 3), ("chunks/chunk-000002.npz", 3)]
    assert dataset_summary(damaged)["groups"] == {"a": 2, "b": 2}
    assert not repair_dataset(damaged).lost  # nothing left to repair

    with DatasetWriter(damaged, metadata={"sensor": "gelslim"}) as writer:  # appending still works
        writer.append(record(10))
    np.testing.assert_array_equal(open_dataset(damaged).read(["index"])["index"], [0, 1, 2, 9, 10])


def test_a_missing_chunk_is_lost_too(tmp_path):
    with DatasetWriter(tmp_path, schema=SCHEMA, chunk_size=4) as writer:
        for i in range(8):
            writer.append(record(i))
    (tmp_path / "chunks" / "chunk-000000.npz").unlink()
    with pytest.raises(CorruptChunkError, match="listed chunk cannot be read"):
        open_dataset(tmp_path).read(["index"])
    report = repair_dataset(tmp_path)
    assert report.lost_records == 4 and report.moved_to == (None,)
    np.testing.assert_array_equal(open_dataset(tmp_path).read(["index"])["index"], [4, 5, 6, 7])


def test_repair_refuses_while_a_writer_runs_and_what_it_cannot_repair(damaged, tmp_path):
    with DatasetWriter(damaged):
        with pytest.raises(DatasetLockedError, match=f"process {os.getpid()}"):
            repair_dataset(damaged)
    (damaged / "manifest.json").write_text("{not json")
    with pytest.raises(CorruptDatasetError, match="manifest.json: not valid JSON"):
        repair_dataset(damaged)
    with pytest.raises(FileNotFoundError, match="not a tactojax dataset"):
        repair_dataset(tmp_path / "nothing")
