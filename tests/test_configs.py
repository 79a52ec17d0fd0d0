"""The config classes: light to import, and documented one line per setting with a pointer to where each
choice is measured."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

import mosegpipe.configs as configs
from mosegpipe.pipeline import PipelineConfig
from mosegpipe.training.loop import TrainConfig
from mosegpipe.viz.common import VizConfig

DOCUMENTED = (*(getattr(configs, name) for name in configs.__all__), PipelineConfig, TrainConfig, VizConfig)


@pytest.mark.parametrize("config", DOCUMENTED, ids=lambda c: c.__name__)
def test_every_setting_has_one_line_and_the_class_says_where_it_is_measured(config: type) -> None:
    doc = inspect.getdoc(config) or ""
    head, _, attributes = doc.partition("\nAttributes:\n")
    assert "docs/" in head, f"{config.__name__}: no pointer to where its choices are measured"
    lines = attributes.splitlines()
    assert all(line.startswith("    ") and not line.startswith("     ") for line in lines), (
        f"{config.__name__}: an attribute's doc runs over one line"
    )
    documented = [line.split(":")[0].strip() for line in lines]
    assert documented == [f.name for f in dataclasses.fields(config)], config.__name__
