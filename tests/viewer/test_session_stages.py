"""The viewer's stages while the camera moves: level of detail where the feature
table lets the scene's integrator and reconstruction draw with it, else the
coarse stage at the scene's own level of detail."""

from __future__ import annotations

import pytest

from helpers import GERRIS


@pytest.fixture(scope="module")
def session():
    import exabricks as eb
    from exabricks.viewer.session import Session

    return Session(eb.open(GERRIS, fields=["T"], cache=False), options={"size": (32, 32)})


@pytest.mark.parametrize("lighting, settings, lod", [
    ({}, {}, 2.0), ({"integrator": "shadow"}, {}, 2.0), ({"integrator": "path"}, {}, 0.0),
    ({}, {"reconstruction": "vertex"}, 0.0), ({}, {"reconstruction": "nearest"}, 0.0)])
def test_a_moving_camera_takes_level_of_detail_where_the_frame_can(session, lighting, settings, lod):
    from exabricks.viewer.session import MOVING_LOD

    doc = {**session.doc, "lighting": {**session.doc.get("lighting", {}), **lighting},
           **settings}
    scene = session.check(doc)
    (stage, coarse), = session.stages(scene, moving=True)
    assert stage == "coarse" and coarse.settings.lod == (MOVING_LOD if lod else 0.0)
    session.draw(stage, coarse)  # and it draws


def test_a_path_traced_frame_refines_in_sight(session):
    from exabricks.viewer.session import PATH_REFINE

    doc = {**session.doc, "lighting": {**session.doc.get("lighting", {}), "integrator": "path"},
           "spp": PATH_REFINE ** 2}
    stages = [stage for stage, _ in session.stages(session.check(doc))]
    assert stages == ["coarse", "full", f"{PATH_REFINE} spp", "converged"]
