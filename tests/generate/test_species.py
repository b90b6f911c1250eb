"""The species library: every file validates, bad input is reported precisely, and generated plants match
Guo et al. 2018, Table 2 (H, |B|, l_B within 30 %)."""

import shutil

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
def scenes(tmp_path, monkeypatch):
    folder = tmp_path / "scenes" / "species"
    folder.mkdir(parents=True)
    shutil.copy(species_dir() / "laurel.toml", folder / "laurel.toml")
    monkeypatch.setenv("PLANTBENCH_SCENES", str(tmp_path / "scenes"))
    # the species registry discovers files once; give it a fresh start, and another after the test
    species.reset()
    yield folder
    monkeypatch.undo()
    species.reset()


def test_out_of_range_value_names_file_field_and_range(scenes):
    text = (scenes / "laurel.toml").read_text().replace("apical_control = 0.5", "apical_control = 1.5")
    (scenes / "laurel.toml").write_text(text)
    with pytest.raises(InputError) as exc:
        load_species("laurel")
    msg = str(exc.value)
    assert "laurel.toml" in msg and "growth.apical_control" in msg and "less than or equal to 0.95" in msg


def test_unknown_field_and_bad_choice_are_errors(scenes):
    text = (scenes / "laurel.toml").read_text()
    (scenes / "laurel.toml").write_text(text.replace("[roots]", "[roots]\nwhorls = 3"))
    with pytest.raises(InputError, match=r"roots\.whorls: unknown field"):
        load_species("laurel")
    (scenes / "laurel.toml").write_text(text.replace('arrangement = "spiral"', 'arrangement = "zigzag"'))
    with pytest.raises(InputError, match=r"leaves\.arrangement"):
        load_species("laurel")


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
