"""Campaign files: expansion into cases, and bad files refused naming the file and the field."""

import tomllib
from pathlib import Path

import pytest

from sil import scenario as scenarios
from sil.campaign.spec import CampaignError, load
from sil.campaign.tomlw import dumps
from tests.campaign.conftest import SMALL


def test_cases_pair_controllers_on_the_same_engine_and_seed(write):
    c = load(write(SMALL))
    assert len(c.cases) == (2 + 1) * 2
    nominal, *varied = [c.cases[i : i + 2] for i in range(0, 6, 2)]
    assert [x.values["controller.kind"] for x in nominal] == ["mrac", "pid"]
    assert all(x.sample == -1 and "plant.pump_gain" not in x.values for x in nominal)
    for mrac, pid in varied:
        same = {k: v for k, v in mrac.values.items() if k != "controller.kind"}
        assert same == {k: v for k, v in pid.values.items() if k != "controller.kind"}
        assert 0.8 <= mrac.values["plant.pump_gain"] <= 1.2
    s = scenarios.parse(varied[0][1].scenario_toml, "case", Path("."))
    assert s.controller.kind == "pid" and s.duration_s == 3
    assert s.plant.pump_gain == varied[0][1].values["plant.pump_gain"]
    assert s.seed == varied[0][1].values["seed"]
    again = load(write(SMALL, "again.toml"))
    assert [x.digest for x in again.cases] == [x.digest for x in c.cases]


def test_shipped_campaigns_load():
    shipped = sorted(Path("sil/campaign/library").glob("*.toml"))
    assert {p.stem for p in shipped} >= {"engine-variation", "bus-faults"}
    sizes = {p.stem: len(load(p).cases) for p in shipped}
    assert sizes["engine-variation"] == 1500


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('name = "small"', 'name = "small"\ncolour = "red"', "unknown field 'colour'"),
        ('base = "thesis-5.4-staircase"', 'base = "no-such-scenario"', "field 'base'"),
        ("samples = 2", "samples = -1", "field 'samples'"),
        ("seed = 4", "seed = 4.5", "field 'seed'"),
        ("nominal = true", "nominal = 1", "field 'nominal'"),
        ("[sweep]", '[invariants]\negt_margin_K = "a lot"\n[sweep]', "'invariants.egt_margin_K'"),
        ("[sweep]", "[invariants]\nmargin = 3\n[sweep]", "unknown field 'invariants.margin'"),
    ],
)
def test_bad_top_level_fields_are_named(write, old, new, message):
    assert old in SMALL
    with pytest.raises(CampaignError, match=message) as err:
        load(write(SMALL.replace(old, new, 1)))
    assert "campaign.toml" in str(err.value)


def test_a_sample_outside_the_scenario_range_names_the_run_and_field(write):
    text = SMALL.replace("uniform = [0.8, 1.2]", "uniform = [1.5, 2.5]")
    with pytest.raises(CampaignError) as err:
        load(write(text))
    msg = str(err.value)
    assert "campaign.toml (run 00002" in msg and "field 'plant.pump_gain'" in msg


def test_bad_distribution_and_sweep_are_named(write):
    with pytest.raises(CampaignError, match=r"field 'sample.plant.pump_gain'"):
        load(write(SMALL.replace("{ uniform = [0.8, 1.2] }", "{ triangle = [1, 2] }")))
    with pytest.raises(CampaignError, match=r"field 'sweep.controller.kind'"):
        load(write(SMALL.replace('["mrac", "pid"]', "[]")))
    with pytest.raises(CampaignError, match=r"field 'controller.kind'"):
        load(write(SMALL.replace('["mrac", "pid"]', '["mrac", "lqr"]')))


def test_bad_bus_fault_in_a_variant_names_its_field(write):
    from tests.campaign.conftest import BUS

    with pytest.raises(CampaignError, match=r"field 'bus_fault\[0\].ids'"):
        load(write(BUS.replace('ids = ["PlantSensors"]', 'ids = ["PlantSensorz"]', 1)))
    with pytest.raises(CampaignError, match=r"field 'bus_fault\[0\].detect'"):
        load(write(BUS.replace('detect = "E2E"', 'detect = "CRC"')))


def test_toml_writer_round_trips_every_shipped_scenario():
    for path in sorted(scenarios.SCENARIO_DIR.glob("*.toml")):
        data = tomllib.loads(path.read_text())
        assert tomllib.loads(dumps(data)) == data, path.name


@pytest.mark.parametrize(
    "old, new, field",
    [
        ("duration_s = 3", "duration_s = nan", "duration_s"),
        ("uniform = [0.8, 1.2]", "uniform = [nan, 1.2]", r"sample.plant.pump_gain.uniform\[0\]"),
        ("uniform = [0.8, 1.2]", "uniform = [0.8, inf]", r"sample.plant.pump_gain.uniform\[1\]"),
        (
            '["mrac", "pid"]',
            '["mrac", "pid"]\n"plant.pump_gain" = [-inf]',
            r"sweep.plant.pump_gain",
        ),
        (
            "[sweep]",
            "[invariants]\nmax_thrust_rise_s = inf\n[sweep]",
            "invariants.max_thrust_rise_s",
        ),
        (
            "[sweep]",
            "[[variant]]\nname='v'\n[[variant.fault]]\nvalue = nan\n[sweep]",
            r"variant\[0\].fault\[0\].value",
        ),
    ],
)
def test_nan_and_inf_are_refused_naming_the_file_and_field(write, old, new, field):
    assert old in SMALL
    with pytest.raises(
        CampaignError, match=rf"campaign.toml: field '{field}.*': expected a finite"
    ):
        load(write(SMALL.replace(old, new, 1)))


def test_distributions_too_wide_for_floats_are_refused(write):
    wide = SMALL.replace("uniform = [0.8, 1.2]", "uniform = [-1e308, 1e308]")
    with pytest.raises(CampaignError, match=r"'sample.plant.pump_gain.uniform'.*finite width"):
        load(write(wide))
    huge = SMALL.replace("uniform = [0.8, 1.2]", "normal = [1.7e308, 1e308]")
    with pytest.raises(CampaignError, match=r"'sample.plant.pump_gain'.*draws are finite"):
        load(write(huge))


def test_a_campaign_too_large_to_check_is_refused_before_it_is_built(write):
    from sil.campaign.spec import MAX_CASES

    huge = SMALL.replace("samples = 2", "samples = 1000000")  # 2,000,002 runs
    with pytest.raises(
        CampaignError, match=rf"'samples': expected a campaign of at most {MAX_CASES}"
    ):
        load(write(huge))
