"""Reading and writing: sequence files (via synth), recordings of your own (PLUS sequence
metafiles, NRRD, image folders, videos), PLUS output of results, OpenIGTLink streaming and
overlay animations."""

from ._errors import RecordingError, StreamError
from ._igtl import IGTLStreamer
from ._metaimage import PlusSequence, read_plus, write_plus
from ._overlay import overlay_frames, write_overlay
from ._recording import load_recording, needle_tip_matrix, save_plus_sequence, sequence_to_plus

__all__ = ["IGTLStreamer", "PlusSequence", "RecordingError", "StreamError", "load_recording",
           "needle_tip_matrix", "overlay_frames", "read_plus", "save_plus_sequence",
           "sequence_to_plus", "write_overlay", "write_plus"]
