"""Every registered stage is of a documented kind and its objects answer that kind's call."""

from __future__ import annotations

import inspect

from weldcell.sdk.plugins import PluginManager
from weldcell.sdk.stages import STAGE_KINDS


def test_every_first_party_stage_answers_its_kind_protocol():
    reg = PluginManager(discover=True).registry
    stages = [e for e in reg.all("stage") if e.provider.distribution == "weldcell"]
    assert len(stages) >= 7
    for entry in stages:
        spec = entry.descriptor
        assert spec.kind in STAGE_KINDS, f"{spec.name}: kind {spec.kind!r} is not documented in sdk/stages.py"
        protocol = STAGE_KINDS[spec.kind]
        if any(f.is_required() for f in spec.settings.model_fields.values()):
            continue  # needs the user's data to exist (detector.onnx: a model file); tested with its plugin
        stage = spec.factory(spec.settings())
        for name, member in vars(protocol).items():
            if name.startswith("_") and name != "__call__" or not callable(member):
                continue
            assert callable(getattr(stage, name, None)), f"{spec.name} lacks {name}() of kind {spec.kind}"
            wanted = [p for p in inspect.signature(member).parameters if p != "self"]
            got = inspect.signature(getattr(stage, name)).parameters
            required = [p for p in wanted if p not in ("kwargs",)][:1]
            assert all(p in got or any(q.kind == q.VAR_POSITIONAL for q in got.values()) for p in required), (
                f"{spec.name}.{name} does not take {required}"
            )
