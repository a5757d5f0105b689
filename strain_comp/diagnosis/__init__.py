"""The residual loop: find what a calibration lacks on measured data, add it, report it
(``loop.diagnose``; ``conditions`` runs it under each tare and measurement-chain hypothesis)."""
