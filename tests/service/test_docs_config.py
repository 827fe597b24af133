"""docs/configuration.md's defaults tables are the settings models' (regenerated and compared)."""

from wrenchd.models.gate import GateConfig
from wrenchd.service.docs_config import PAGE, markdown, render_page


def test_committed_defaults_tables_match_the_models():
    committed = PAGE.read_text()
    assert render_page(committed) == committed, (
        "docs/configuration.md is out of date: run `python -m wrenchd.service.docs_config "
        "--write` and commit the page")


def test_every_gate_field_has_a_row_with_its_default():
    text = markdown()
    section = text[text.index("### `[arms.pipeline.gate]` (GateConfig)"):].split("\n### ")[0]
    for key in GateConfig.model_fields:
        assert f"| `{key}` |" in section, key
    assert "| `enter_sigma` | `5.0` |" in section
