"""What several test packages share, each thing once:

- :mod:`~tests.helpers.waiting`: ``wait_for`` (poll until a condition holds or fail naming it);
- :mod:`~tests.helpers.recordings`: small recordings written on the fly (real JPEG/PNG bytes on
  an exact timestamp grid) and the file-camera configs that replay them;
- :mod:`~tests.helpers.shots`: rendered stereo shots with their ground truth (plane and room);
- :mod:`~tests.helpers.boards`: rendered calibration boards through known lenses;
- :mod:`~tests.helpers.ring`: the real ring of four fisheyes in the shared data, read into a
  ``Rig`` and its frames (also used by ``bench.ring_consistency``);
- :mod:`~tests.helpers.service`: service settings for a replayed recording and ``create_app``
  run in process (``InProcessServer``) or under a real uvicorn server in a thread
  (``LiveServer``);
- :mod:`~tests.helpers.offline`: noisy recordings of a rendered plane for the offline-processing
  tests, and output trees by file;
- :mod:`~tests.helpers.disks`: a real full disk (a small tmpfs);
- :mod:`~tests.helpers.inputs`: what a test needs from outside the repo (the real data, tools CI
  installs): skipped locally and counted in one line, a failure under ``RIG_REQUIRE_TEST_INPUTS``;
- :mod:`~tests.helpers.command`: the ``rig`` console command in subprocesses (one-shot runs and
  ``rig serve`` waited for until it answers).

The fixtures built on them (the small rendered recording, the session's LUT cache, server
factories) are in ``tests/conftest.py``.
"""
