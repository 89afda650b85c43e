"""The YAML files a user gives (scenario files, recording.yaml) are read with bounded work and memory: a
YAML bomb and an oversized or binary file are each refused in one short line."""
import os
import tracemalloc

import numpy as np
import pytest

from softsbi.core.errors import DataError
from softsbi.core.yamlfile import MAX_ALIAS_NODES, MAX_YAML_BYTES, load_yaml
from softsbi.data.recording import read_recording
from softsbi.scenarios.spec import load_scenario_file


def _bomb(levels: int, width: int = 9, field: str = "name") -> str:
    """Billion laughs: ``width`` aliases per level, ``levels`` levels; the last level is a field's value."""
    lines = ["a0: &a0 [" + ", ".join(['"lol"'] * width) + "]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]" for i in range(1, levels)]
    return "\n".join(lines) + f"\n{field}: *a{levels - 1}\n"


def _refused(load, path):
    tracemalloc.start()
    try:
        with pytest.raises(DataError) as err:
            load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return str(err.value), peak


@pytest.mark.parametrize("levels", [7, 9])
def test_a_yaml_bomb_is_refused_while_parsing(tmp_path, levels):
    """9 levels of 9 aliases took 80 s and 3.3 GB before their one-line rejection (the message repr'd the
    expanded value); now the aliases are counted as the file is parsed."""
    scenario = tmp_path / "bomb.yaml"
    scenario.write_text("format: softsbi-scenario/1\n" + _bomb(levels))
    rec = tmp_path / "rec"
    (rec / "clouds").mkdir(parents=True)
    np.save(rec / "clouds" / "000.npy", np.zeros((4, 3)))
    (rec / "recording.yaml").write_text("format: softsbi-recording/1\n" + _bomb(levels, field="source"))
    for load, path in ((load_scenario_file, scenario), (read_recording, rec)):
        line, peak = _refused(load, path)
        assert path.name in line and str(MAX_ALIAS_NODES) in line and "\n" not in line  # the file and the limit
        assert len(line) < 300 and peak < 200e6, (len(line), peak)


def test_aliases_within_the_budget_are_read():
    assert load_yaml("a: &p [1, 2]\nb: *p\n", "x.yaml") == {"a": [1, 2], "b": [1, 2]}


def test_an_oversized_or_binary_yaml_file_is_refused_before_parsing(tmp_path):
    rec = tmp_path / "rec"
    (rec / "clouds").mkdir(parents=True)
    np.save(rec / "clouds" / "000.npy", np.zeros((4, 3)))
    (rec / "recording.yaml").write_bytes(os.urandom(MAX_YAML_BYTES + 1))
    line, _ = _refused(read_recording, rec)
    assert "recording.yaml" in line and "4.0 MB" in line and f"{MAX_YAML_BYTES // 2**20} MB" in line  # size, limit
    (rec / "recording.yaml").write_bytes(b"format: \xff\xfe" + os.urandom(1000))
    line, _ = _refused(read_recording, rec)
    assert "recording.yaml" in line and "byte 8" in line and "UTF-8" in line

