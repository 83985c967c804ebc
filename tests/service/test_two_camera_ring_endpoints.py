"""The ring's endpoints on today's two-camera rig: its one pair is ``left-right`` (``/range?pair=``
gives today's /range), there is no panorama (404 saying why), an unknown pair is a 404 naming
the pair it has, and /health has no pairs section."""

from __future__ import annotations

from tests.helpers.service import StartApp


def test_the_two_camera_rig_has_one_pair_and_no_panorama(start_app: StartApp) -> None:
    live = start_app()
    c = live.client
    plain = c.get("/range", params={"format": "npy"})
    named = c.get("/range", params={"format": "npy", "pair": "left-right"})
    assert plain.status_code == named.status_code == 200
    if plain.headers["X-Frame-Seq"] == named.headers["X-Frame-Seq"]:
        assert plain.content == named.content
    unknown = c.get("/range", params={"pair": "cam1-cam2"})
    assert unknown.status_code == 404
    assert unknown.json() == {"detail": "no pair 'cam1-cam2'; the rig's pairs: left-right"}
    for path in ("/panorama", "/panorama/info", "/panorama/colorized"):
        r = c.get(path)
        assert r.status_code == 404 and "two-camera rig" in r.json()["detail"], path
    assert c.get("/health").json()["pairs"] is None
