"""Longwall simulator: scenario → truth trajectory → exact IMU → sensor models → recording.

The simulator is a separate product that writes recordings in the ``shearer-recording/1``
format; the fusion engine never imports it. Entry points live in :mod:`fusion.sim.simulate`
(``simulate``, ``load_scenario``, ``list_scenarios``), :mod:`fusion.sim.worlds` (``draw_world``:
randomized longwall worlds from ``WorldRanges``) and :mod:`fusion.sim.plot` (``plot_truth``).
"""
