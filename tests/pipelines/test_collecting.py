"""How a pipeline's task specs ("pick_place", "pick_place:bread") become ``sigma-data collect``'s tasks and
variations (pipelines/collecting.py)."""

from __future__ import annotations

import pytest

from pipelines.collecting import split_variations


def test_whole_tasks_collect_every_variation():
    assert split_variations(["lift", "stack"]) == (["lift", "stack"], "all")


def test_one_variation_of_a_task():
    assert split_variations(["pick_place:bread"]) == (["pick_place"], "bread")


def test_whole_tasks_beside_single_variations_keep_all_of_theirs():
    tasks, variations = split_variations(["stack", "pick_place:can", "pick_place:bread"])
    assert tasks == ["stack", "pick_place"]
    assert variations.split(",") == ["red_on_green", "green_on_red", "can", "bread"]


@pytest.mark.parametrize(
    ("spec", "message"), [("pick_place:pizza", "unknown variation 'pizza'"), ("juggle", "unknown task")]
)
def test_unknown_names_are_refused(spec, message):
    with pytest.raises(ValueError, match=message):
        split_variations([spec])
