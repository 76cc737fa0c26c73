"""Silence for one call: OpenCV's log and C libraries that print to stderr themselves.

Decoders of hostile data (libpng, libjpeg, libaom) complain on file descriptor 2
before OpenCV returns its failure; tpsv reports each failure as one line of its
own, so their output is kept off the terminal while they run.
"""

from __future__ import annotations

import contextlib
import os
import sys

from cv2.utils import logging as cv_logging


@contextlib.contextmanager
def quiet_stderr():
    """Keep OpenCV's log and the C libraries' direct prints off stderr for one call.

    OpenCV's log level is restored afterwards. libpng and libjpeg write to file
    descriptor 2 themselves, so that descriptor points at the null device
    meanwhile (another thread's stderr output in that window is lost too; the
    CLI decodes before it starts any).
    """
    level = cv_logging.getLogLevel()
    cv_logging.setLogLevel(cv_logging.LOG_LEVEL_SILENT)
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all: nothing to protect
        saved = None
    try:
        if saved is not None:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)
        yield
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
        cv_logging.setLogLevel(level)


