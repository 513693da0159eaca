"""What every video of a batch run shares, and which of it changes a result (the resume key)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from anra_torch.video import ROI, CalibrationTable, PathLike, load_calibration, parse_roi

__all__ = ["BatchOptions"]


@dataclass(frozen=True)
class BatchOptions:
    """What every video of a batch run shares (picklable, sent to Dask workers as is).

    Attributes:
        dt: frame period in s overriding the files, or None.
        dx: pixel size in mm overriding the files, or None.
        diagnose: also diagnose each video and forecast held-out frames.
        dtype: ``"float32"`` (fast) or ``"float64"``.
        fit_fraction: fraction of the frames diagnosed with ``diagnose``.
        resample: resample non-uniform timestamps (FLIR JPEG folders) onto their median step
            (:func:`anra_torch.video.resample_uniform`); otherwise such a video is an error row.
        roi: region ``(x0, y0, width, height)`` in px analysed in every video (or its text ``"X0,Y0,W,H"``,
            which :func:`~anra_torch.batch.run_batch` parses), or None.
        precision: read each video in time chunks and stop at this relative standard error (e.g. 0.001;
            :func:`~anra_torch.estimation.estimate_chunked`), or None.
        calibration: apparent -> true temperature table applied to every video, or None; the path of a
            ``true,apparent`` CSV is read once by :func:`~anra_torch.batch.run_batch` (Dask workers get
            the table).
        device: the torch device the estimates (and diagnoses) compute on; not a result parameter.

    Shape:
        No tensors.
    """

    dt: float | None = None
    dx: float | None = None
    diagnose: bool = False
    dtype: str = "float32"
    fit_fraction: float = 0.6
    resample: bool = False
    roi: ROI | str | None = None
    calibration: CalibrationTable | PathLike | None = None
    precision: float | None = None
    device: str = "cpu"

    def checked(self) -> BatchOptions:
        """These options checked, the region parsed and the calibration read (once, here).

        Raises:
            ValueError: a malformed region, a bad calibration file, a precision outside (0, 1).
        """
        roi, calibration, precision = self.roi, self.calibration, self.precision
        if roi is not None:
            roi = parse_roi(roi if isinstance(roi, str) else ",".join(str(v) for v in roi))
        if calibration is not None and not isinstance(calibration, CalibrationTable):
            calibration = load_calibration(calibration)
        if precision is not None and not (isinstance(precision, int | float) and 0 < precision < 1):
            raise ValueError(f"precision must be a relative standard error in (0, 1), got {precision!r}")
        return replace(self, roi=roi, calibration=calibration)

    def parameters(self) -> dict[str, Any]:
        """Every option that changes a result, JSON-ready: the ``parameters`` cell of the resume key.

        ``diagnose`` is not one (a row without diagnosis is simply not done for a run that asks for it); the
        calibration table counts by its values (a SHA-256 prefix), not by its file name.
        """
        if isinstance(self.roi, str) or not isinstance(self.calibration, CalibrationTable | None):
            return self.checked().parameters()  # as a run reads them
        digest = None
        if self.calibration is not None:
            values = np.concatenate(
                [
                    np.asarray(self.calibration.true, np.float64),
                    np.asarray(self.calibration.apparent, np.float64),
                ]
            )
            digest = f"sha256:{hashlib.sha256(values.tobytes()).hexdigest()[:16]}"
        return {
            "dt": self.dt,
            "dx": self.dx,
            "dtype": self.dtype,
            "resample": self.resample,
            "roi": list(self.roi) if self.roi is not None else None,
            "calibration": digest,
            "fit_fraction": self.fit_fraction,
            "precision": self.precision,
        }
