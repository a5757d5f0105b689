"""The residual loop: find what a calibration lacks on measured data, add it, report it.

``loop.diagnose`` runs it; ``candidates`` builds the candidate effects, ``selection`` holds
the statistics that choose among them, ``report`` the results and readings, and
``conditions`` the tare and measurement-chain hypotheses tried around the loop.
"""
