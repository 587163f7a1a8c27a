"""Reading and writing: sequence files (via synth), recordings of your own (DICOM cine loops,
PLUS sequence metafiles, NRRD, image folders, videos), PLUS output of results, OpenIGTLink
streaming and overlay animations."""

from ._atomic import atomic_write
from ._errors import RecordingError, StreamError
from ._frames import VIDEO_SUFFIXES, sidecar_path
from ._igtl import IGTLStreamer
from ._limits import MAX_GAP_S, check_allocation, check_fps, check_meta_numbers
from ._metaimage import PlusSequence, plus_outputs, read_plus, write_plus
from ._overlay import overlay_frames, write_overlay
from ._recording import (
           load_recording,
           needle_tip_matrix,
           parse_crop,
           parse_spacing,
           save_plus_sequence,
           sequence_to_plus,
)

__all__ = ["atomic_write", "check_allocation", "check_fps", "check_meta_numbers", "IGTLStreamer",
           "load_recording", "MAX_GAP_S", "needle_tip_matrix", "overlay_frames", "parse_crop",
           "parse_spacing", "plus_outputs", "PlusSequence", "read_plus", "RecordingError",
           "save_plus_sequence", "sequence_to_plus", "sidecar_path", "StreamError",
           "VIDEO_SUFFIXES", "write_overlay", "write_plus"]
