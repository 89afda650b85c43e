"""One atomic writer and one reader for every JSON result (check.json, diagnosis.json, report.json, ...): a failed
write leaves the old file and no ``.tmp``; a damaged file is one line naming it and the command that rewrites it."""
import errno
import json

import pytest

import softsbi.core.jsonfile as jsonfile
import softsbi.core.results as results
from softsbi.core.errors import SoftsbiError
from softsbi.core.results import write_result
from result_helpers import check_result, training_report_doc


def test_a_result_over_a_folder_is_one_line_and_leaves_no_tmp(tmp_path):
    target = tmp_path / "diagnosis.json"
    target.mkdir()
    with pytest.raises(SoftsbiError) as err:
        write_result(target, check_result())
    assert str(target) in str(err.value) and "is a folder" in str(err.value) and "\n" not in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diagnosis.json"] and target.is_dir()


def test_a_full_disk_keeps_the_old_file_and_leaves_no_tmp(tmp_path, monkeypatch):
    from softsbi.core.results import ResultUnwritable, write_json_atomic
    target = tmp_path / "check.json"
    write_json_atomic(target, {"old": 1})

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(jsonfile.os, "fsync", full)
    with pytest.raises(ResultUnwritable) as err:
        write_json_atomic(target, {"new": 2})
    line = str(err.value)
    assert f"'{target}'" in line and "\n" not in line  # the file
    assert "--out" not in line and err.value.errno == errno.ENOSPC
    assert json.loads(target.read_text()) == {"old": 1} and not (tmp_path / "check.json.tmp").exists()


@pytest.mark.parametrize("text, problem", [("{bad", "not valid JSON"), ('{"parameters": [1, 2', "not valid JSON"),
                                           ("", "empty"), ("{}", "lacks 'parameters', 'posterior_median'"),
                                           ("[1]", "not an object")])
def test_a_damaged_file_is_one_line_naming_it_and_the_command_that_rewrites_it(tmp_path, text, problem):
    from softsbi.core.results import ResultDamaged, read_json
    path = tmp_path / "report.json"
    path.write_text(text)
    with pytest.raises(ResultDamaged) as err:
        read_json(path, "`softsbi fit ...`", ("parameters", "posterior_median"))
    line = str(err.value)
    assert err.value.path == path and problem in err.value.problem
    assert line.startswith(f"'{path}'") and "`softsbi fit ...`" in line and "\n" not in line  # the file, the command


def test_a_check_json_of_schema_3_reads_its_regions_and_phases_words_as_typed_fields():
    """check.json files kept ``regions_from`` / ``phases_from`` in words; a check now stores the handle and whether
    the phases are the keyframes' (the words are report.text's), and an old file reads back with the same meaning."""
    new = check_result(grasp_handle="left", phases_at_keyframes=True)
    doc = json.loads(json.dumps(results.to_json(new)))
    assert doc["grasp_handle"] == "left" and doc["phases_at_keyframes"] is True and "regions_from" not in doc
    assert results.from_json(results.CheckResult, doc) == new
    old = {k: v for k, v in doc.items() if k not in ("grasp_handle", "phases_at_keyframes")}
    back = results.from_json(results.CheckResult, {**old, "schema": 3, "regions_from": "the grasp of handle 'left'",
                                                   "phases_from": "the scenario's keyframes"})
    assert back == new
    one = results.from_json(results.CheckResult, {**old, "schema": 3, "regions_from": "the grasp",
                                                  "phases_from": "equal thirds of the motion"})
    assert one.grasp_handle is None and one.phases_at_keyframes is False


def test_mapping_and_sequence_fields_rebuild_their_dataclass_values():
    """``typing.get_origin(Mapping[...])`` is ``collections.abc.Mapping``: such fields (a training report's
    ``contraction``) read back as their dataclasses, not as dicts, and so do ``Sequence[...]`` and ``list[...]``."""
    from collections.abc import Mapping, Sequence
    from dataclasses import dataclass

    from softsbi.core.results.fitreport import Contraction, TrainingReport
    from softsbi.core.results import Role

    @dataclass(frozen=True)
    class Holder:
        by_name: Mapping[str, Contraction]
        in_order: Sequence[Contraction]
        listed: list[Role]

    doc = {"by_name": {"a": {"width_ratio": 0.5, "informed": True}}, "in_order": [{"width_ratio": 1}],
           "listed": [Role.NAMED.value]}
    back = jsonfile._build(Holder, doc)
    assert back.by_name == {"a": Contraction(width_ratio=0.5, informed=True)}
    assert back.in_order == (Contraction(width_ratio=1.0),) and back.listed == [Role.NAMED]
    rep = TrainingReport.from_json(training_report_doc())
    assert rep.contraction["a"] == Contraction(width_ratio=0.4, informed=True)
    assert TrainingReport.from_json(rep.to_json()) == rep
