"""Pure-Python GigE Vision client: GVCP control (`device`), GenApi features
(`features`), GVSP reception (`stream`), and `GigECamera` tying them together."""
from rig.drivers.gige.camera import GigECamera, parse_camera_url
from rig.drivers.gige.device import ControlConfig, GigEDevice, GvcpError, GvcpTimeout, discover
from rig.drivers.gige.stream import Frame, GvspStream, StreamConfig, StreamStats

__all__ = ["GigECamera", "parse_camera_url", "ControlConfig", "GigEDevice", "GvcpError",
           "GvcpTimeout", "discover", "Frame", "GvspStream", "StreamConfig", "StreamStats"]
