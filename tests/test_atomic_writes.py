"""Every record that matters is written atomically: a full disk leaves the previous file intact and
says so in one line naming the file; GIFs stream to disk with bounded memory."""

from __future__ import annotations

import errno
import os
import re
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from sb3_pm.baselines import make_team
from sb3_pm.cli import main
from sb3_pm.evaluation import Comparison, evaluate, record_gif
from sb3_pm.evaluation.gif import GifWriter, gif_writer, write_gif
from sb3_pm.experiments.report import write_report
from sb3_pm.files import write_atomic

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_pm"


def disk_full_for(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    """Writes of files named ``name`` fail as on a full disk (when flushed, where a full disk shows)."""
    fsync = os.fsync

    def failing(descriptor: int) -> None:
        if Path(os.readlink(f"/proc/self/fd/{descriptor}")).name.startswith(f".{name}."):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        fsync(descriptor)

    monkeypatch.setattr(os, "fsync", failing)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_evaluate_json_on_a_full_disk_keeps_the_previous_file(tmp_path, monkeypatch, capsys) -> None:
    target = tmp_path / "r.json"
    target.write_text('{"valid": "previous record"}')
    disk_full_for(monkeypatch, "r.json")
    argv = ["evaluate", "--policy", "grazing", "--agents", "2", "--steps", "5", "--episodes", "2"]
    assert main([*argv, "--json", str(target)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sb3-pm evaluate: error: {target}: No space left on device"]
    assert target.read_text() == '{"valid": "previous record"}' and leftovers(tmp_path) == []


def test_compare_outputs_and_the_report_on_a_full_disk(tmp_path, monkeypatch) -> None:
    result = evaluate(make_team("grazing"), "paper-50", n_agents=2, episodes=2, max_cycles=5)
    comparison = Comparison(config={"policies": ["grazing"]})
    comparison.results["grazing"] = [result]
    written = comparison.write(tmp_path)
    before = {path.name: path.read_bytes() for path in written}
    for name in before:
        with monkeypatch.context() as patch:
            disk_full_for(patch, name)
            with pytest.raises(OSError, match=re.escape(f"{tmp_path / name}")) as error:
                comparison.write(tmp_path)
        assert error.value.errno == errno.ENOSPC
        assert {path.name: path.read_bytes() for path in written} == before, name
        assert leftovers(tmp_path) == []
    for name in ("results.md", "command.txt"):
        (tmp_path / name).write_text(name)
    record = {"name": "x", "graphs": ["paper-50"], "seeds": [0], "episodes": 2, "max_cycles": 5}
    record |= {"n_agents": 2, "evaluation_seeds": [0, 1]}
    report = write_report(tmp_path, record, [], reference="grazing")
    previous = report.read_text()
    disk_full_for(monkeypatch, "report.md")
    with pytest.raises(OSError, match="No space left on device"):
        write_report(tmp_path, record | {"name": "y"}, [], reference="grazing")
    assert report.read_text() == previous and leftovers(tmp_path) == []


def test_a_gif_on_a_full_disk_keeps_the_previous_one(tmp_path, monkeypatch) -> None:
    path = tmp_path / "e.gif"
    path.write_bytes(b"GIF89a previous")
    disk_full_for(monkeypatch, "e.gif")
    with pytest.raises(OSError, match="No space left on device") as error:
        record_gif(make_team("random"), "paper-50", path, n_agents=2, max_cycles=3)
    assert error.value.filename == str(path)
    assert path.read_bytes() == b"GIF89a previous" and leftovers(tmp_path) == []


def test_an_error_while_writing_keeps_the_previous_file(tmp_path) -> None:
    path = tmp_path / "a.txt"
    write_atomic(path, "first")
    with pytest.raises(RuntimeError), gif_writer(path):  # the block fails: nothing replaced
        raise RuntimeError
    assert path.read_text() == "first" and leftovers(tmp_path) == []


#: Writes that replace a file in place (a crash or a full disk leaves half of it). Every write of a
#: record goes through sb3_pm.files (write_atomic, atomic_path) or a module's own rename.
IN_PLACE = re.compile(r"\.write_text\(|\.write_bytes\(|\.savefig\(|json\.dump\(|open\([^)]*[\"'][wa]")
#: Writes of temporary files that are renamed into place afterwards.
ALLOWED = {
    ("files.py", ".write_text("),
    ("files.py", ".write_bytes("),
    ("plots.py", ".savefig("),
    ("gif.py", 'open("w'),
    ("checkpoints.py", 'open("w'),  # inside a checkpoint's temporary folder, renamed when whole
    ("plain_state.py", ".write_bytes("),  # into atomic_path's temporary file
}


def test_no_record_is_written_in_place() -> None:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            match = IN_PLACE.search(line)
            if match and (path.name, match.group(0)) not in ALLOWED:
                found.append(f"{path.relative_to(PACKAGE)}:{number}: {line.strip()}")
    assert found == []


def test_a_gif_streams_its_frames_to_disk(tmp_path) -> None:
    """The frames are written as they come: the file grows frame by frame, the writer keeps one
    frame's palette indices, and memory stays bounded however long the episode."""
    path = tmp_path / "e.gif"
    sizes: list[int] = []
    append = GifWriter.append

    def spying(self: GifWriter, frame: np.ndarray) -> None:
        append(self, frame)
        self.handle.flush()
        sizes.append(os.fstat(self.handle.fileno()).st_size)

    # A short recording first, so that the modules drawing and writing load before memory is traced.
    record_gif(make_team("grazing"), "paper-50", tmp_path / "warm-up.gif", n_agents=2, max_cycles=2)
    GifWriter.append = spying  # type: ignore[method-assign]
    try:
        tracemalloc.start()
        record_gif(make_team("grazing"), "paper-50", path, n_agents=2, max_cycles=40)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        GifWriter.append = append  # type: ignore[method-assign]
    assert len(sizes) == 41 and all(later > earlier for earlier, later in zip(sizes, sizes[1:]))
    frame_bytes = 480 * 480 * 3
    assert peak < 12 * frame_bytes  # the 41 frames would be 28 MB; a handful at a time is held
    with Image.open(path) as image:
        assert image.format == "GIF" and image.n_frames == 41 and image.info["loop"] == 0


def test_a_streamed_gif_shows_the_frames_it_was_given(tmp_path) -> None:
    rng = np.random.default_rng(0)
    colors = rng.integers(0, 256, size=(6, 3), dtype=np.uint8)
    frames = []
    for i in range(12):  # few colours, so that the palette holds them exactly
        frame = np.zeros((30, 40, 3), dtype=np.uint8)
        frame[:] = colors[i % 2]
        frame[5 + i : 10 + i, 3 : 3 + 2 * i + 1] = colors[2 + i % 4]
        frames.append(frame)
    frames.append(frames[-1].copy())  # an unchanged frame is still a frame
    path = write_gif(frames, tmp_path / "f.gif", fps=10)
    with Image.open(path) as image:
        decoded = [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(image)]
        assert image.info["duration"] == 100
    assert len(decoded) == len(frames)
    for got, expected in zip(decoded, frames):
        np.testing.assert_array_equal(got, expected)
