"""The species library: every file validates, bad input is reported precisely, and generated plants match
Guo et al. 2018, Table 2 (H, |B|, l_B within 30 %)."""

import shutil
from pathlib import Path

import pytest

from plantbench.errors import InputError
from plantbench.generate import FAMILIES, generate_case, species_stats
from plantbench.paths import species_dir
from plantbench.species import load_species, species

TABLE2 = {  # Guo et al. 2018, Table 2: H (m), |B|, l_B (m)
    "pentagon_maple": (3.92, 1733, 0.501),
    "peach": (4.76, 693, 0.429),
    "laurel": (0.97, 1980, 0.089),
    "maple": (5.21, 1768, 0.306),
    "prunus_triloba": (3.12, 2352, 0.394),
    "cercis": (4.45, 2788, 0.205),
}


def test_library_holds_table2_and_habit_species():
    names = species.names()
    for name in list(TABLE2) + ["american_elm", "crab_apple"]:
        assert name in names
        spec = load_species(name)
        assert spec.name == name and spec.family in FAMILIES


def test_reference_values_are_table2():
    for name, (h, b, lb) in TABLE2.items():
        ref = load_species(name).reference
        assert (ref.height, ref.branches, ref.mean_branch_length) == (h, b, lb)


def test_unknown_species_did_you_mean(tmp_path):
    with pytest.raises(InputError, match="did you mean 'laurel'"):
        generate_case("laurell", 0, tmp_path)


@pytest.fixture
def scratch_species(tmp_path, monkeypatch):
    """A species library of the test's own: ``scratch_species(name)`` copies the shipped ``name.toml`` into it and
    returns its path, for the test to edit before :func:`plantbench.species.load_species` reads it."""
    shipped = species_dir()
    folder = tmp_path / "scenes" / "species"
    folder.mkdir(parents=True)
    monkeypatch.setenv("PLANTBENCH_SCENES", str(tmp_path / "scenes"))
    # the species registry discovers files once; give it a fresh start, and another after the test
    species.reset()

    def copy(name: str) -> Path:
        return Path(shutil.copy(shipped / f"{name}.toml", folder / f"{name}.toml"))

    yield copy
    monkeypatch.undo()
    species.reset()


BAD_INPUT = [  # species, text of its file, what replaces it, what the error names
    ("laurel", "apical_control = 0.5", "apical_control = 1.5",
     ("laurel.toml", "growth.apical_control", "less than or equal to 0.95")),
    ("laurel", "[roots]", "[roots]\nwhorls = 3", ("roots.whorls: unknown field",)),
    ("laurel", 'arrangement = "spiral"', 'arrangement = "zigzag"', ("leaves.arrangement",)),
    ("wp_aspen", "down_angle = 45\n", "down_angle = 450\n",
     ("wp_aspen.toml", "level2.down_angle", "less than or equal to 180")),
    ("wp_aspen", "[level2]", "[level2]\nlobes = 5", ("level2.lobes: unknown field",)),
    ("wp_aspen", 'shape = "tend_flame"', 'shape = "blob"', ("tree.shape",)),
]


@pytest.mark.parametrize(("name", "old", "new", "expected"), BAD_INPUT)
def test_bad_value_names_file_field_and_range(scratch_species, name, old, new, expected):
    """Out-of-range values, unknown fields and bad choices, in a species file of either family."""
    path = scratch_species(name)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    with pytest.raises(InputError) as exc:
        load_species(name)
    msg = str(exc.value)
    assert all(part in msg for part in expected), msg


def test_scale_out_of_range(tmp_path):
    with pytest.raises(InputError, match="scale"):
        generate_case("laurel", 0, tmp_path, scale=1.5)


def test_generated_plants_match_table2_within_30_percent():
    """One full-size plant per Table 2 species (the slow test of this folder, ~20 s)."""
    rows = species_stats(list(TABLE2), seeds=(0,))
    bad = []
    for row in rows:
        h, b, lb = TABLE2[row["species"]]
        assert (row["H_paper"], row["B_paper"], row["l_B_paper"]) == (h, b, lb)
        for key, paper in (("H", h), ("B", b), ("l_B", lb)):
            if abs(row[key] - paper) > 0.3 * paper:
                bad.append(f"{row['species']} {key} = {row[key]:.3f} vs {paper}")
    assert not bad, bad
