"""GET /api/clips/{file}: an event clip, with Range requests (the page's video element seeks).

Only a finished clip directly in the output folder's clips/ is served: the name is one path
part of letters, digits, '_', '.', '-' ending in .mp4 (not .part.mp4), not starting with a dot,
and the file a regular file there (a symbolic link is refused); anything else is 404 (400 for a
name that cannot be one).
"""

from __future__ import annotations

import os
import re
import stat

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import FileResponse

from stereopose.io.sinks.clips import CLIP_SUFFIX, PART_SUFFIX
from stereopose.service.auth import Viewer, console_parts

router = APIRouter(tags=["events"])

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,250}")


@router.get("/api/clips/{file}", response_class=FileResponse,
            responses={200: {"content": {"video/mp4": {}}}, 400: {}, 404: {}})  # fmt: skip
def clip(file: str, session: Viewer, parts=Depends(console_parts)) -> FileResponse:  # noqa: B008
    """The clip (video/mp4)."""
    if not _NAME.fullmatch(file) or ".." in file or not file.endswith(CLIP_SUFFIX):
        raise HTTPException(400, "not a clip name")
    if file.endswith(PART_SUFFIX) or parts.clips_dir is None:
        raise HTTPException(404, "no such clip")
    path = parts.clips_dir / file
    try:
        st = os.lstat(path)
    except OSError:
        raise HTTPException(404, "no such clip") from None
    if not stat.S_ISREG(st.st_mode) or os.path.dirname(os.path.realpath(path)) != os.path.realpath(
        parts.clips_dir
    ):
        raise HTTPException(404, "no such clip")
    return FileResponse(path, media_type="video/mp4", stat_result=st,
                        headers={"Cache-Control": "private, max-age=3600"})  # fmt: skip
