"""File formats (docs/formats.md): subjects, avatars and motions. Loaders validate everything and
raise ``FormatError`` naming the file, the field and the value; writers are atomic."""

from trioman.runtime.formats.avatar import load_avatar, save_avatar
from trioman.runtime.formats.common import FormatError
from trioman.runtime.formats.motion import load_motion, save_motion
from trioman.runtime.formats.subject import Subject, load_subject, save_subject

__all__ = ["FormatError", "Subject", "load_avatar", "save_avatar", "load_motion", "load_subject", "save_motion", "save_subject"]
