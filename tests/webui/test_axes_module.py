"""The pages' scripts take the ankle's axes from the project's one table (device.axes)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from device.axes import AXIS_INDEX, ROTATION_AXES
from server.config import Settings
from tests.server.live_server import running
from webui.app import create_app


def _constant(name: str, text: str) -> object:
    found = re.search(rf"export const {name} = (.*);", text)
    assert found, text
    return json.loads(found.group(1))


@pytest.mark.asyncio
async def test_the_axes_module_is_generated_from_the_device_table(tmp_path: Path) -> None:
    async with running(Settings(data_dir=tmp_path), create_app) as live:
        # The client's base is the API's (/api/v1); the scripts are served beside it.
        r = await live.client.get(str(live.client.base_url.join("/static/js/axes.js")))
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/javascript")
    assert _constant("AXES", r.text) == list(ROTATION_AXES)
    assert _constant("AXIS_INDEX", r.text) == {a: AXIS_INDEX[a] for a in ROTATION_AXES}
    scripts = Path(__file__).parents[2] / "webui" / "static" / "js"
    assert 'from "./axes.js"' in (scripts / "live.js").read_text()
    # progress.js and the session's metrics take their axes from the API's answers.
    for script in ("live.js", "progress.js", "exercise-metrics.js"):  # no copy of the table
        assert '"roll", "pitch", "yaw"' not in (scripts / script).read_text()
