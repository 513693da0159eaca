"""What happens to one recording: read, repair, phases, route, the phase described, and its record.

Every command goes through this one policy (``anra estimate``, ``diagnose``, ``features`` and ``batch`` are
argument parsing and printing around it):

- :mod:`~anra_torch.recording.read`: :func:`open_recording`, in memory or left on disk to be read in chunks;
- :mod:`~anra_torch.recording.phases`: :func:`find_phases` (baseline, heating, cooling, after the camera's
  artefacts are repaired) and which phase describes the recording;
- :mod:`~anra_torch.recording.plan`: a recording's phases and the route of each (small box, whole, in
  chunks); :mod:`~anra_torch.recording.records`: the records of a recording's estimate;
- :mod:`~anra_torch.recording.estimate`: :func:`estimate_recording` / :func:`estimate_recordings`, each phase
  by its route, the described phase and its record;
- :mod:`~anra_torch.recording.decimate`: the block-averaged copy a camera-sized recording is diagnosed on;
- :mod:`~anra_torch.recording.phase_diagnosis`: :func:`diagnose_recording`, every phase diagnosed on its own;
- :mod:`~anra_torch.recording.diagnose`: :func:`open_for_diagnosis` and :func:`diagnose_video`, the
  diagnosis of a recording and its record.
"""

from anra_torch.recording.decimate import (
    DIAGNOSE_VALUES,
    camera_copy,
    decimated_video,
    decimation,
    signal_box,
)
from anra_torch.recording.diagnose import (
    RecordingDiagnosis,
    check_memory,
    diagnose_video,
    diagnosis_copy,
    open_for_diagnosis,
)
from anra_torch.recording.estimate import estimate_recording, estimate_recordings, phase_diffusivities
from anra_torch.recording.phase_diagnosis import INNER_SPLITS, PhaseDiagnosis, diagnose_recording, flash_hints
from anra_torch.recording.phases import (
    MIN_PHASE_FRAMES,
    PHASE_COPY_VALUES,
    SOURCE_FREE,
    find_phases,
    phase_preference,
    whole_recording,
)
from anra_torch.recording.plan import on_disk_above, reads_in_chunks
from anra_torch.recording.read import input_record, open_recording
from anra_torch.recording.records import PhaseEstimate, RecordingEstimate, phase_head

__all__ = [
    "DIAGNOSE_VALUES",
    "INNER_SPLITS",
    "MIN_PHASE_FRAMES",
    "PHASE_COPY_VALUES",
    "SOURCE_FREE",
    "PhaseDiagnosis",
    "PhaseEstimate",
    "RecordingDiagnosis",
    "RecordingEstimate",
    "camera_copy",
    "check_memory",
    "decimated_video",
    "decimation",
    "diagnose_recording",
    "diagnose_video",
    "diagnosis_copy",
    "estimate_recording",
    "estimate_recordings",
    "find_phases",
    "flash_hints",
    "input_record",
    "on_disk_above",
    "open_for_diagnosis",
    "open_recording",
    "phase_diffusivities",
    "phase_head",
    "phase_preference",
    "reads_in_chunks",
    "signal_box",
    "whole_recording",
]
