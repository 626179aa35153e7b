"""Volume rendering: packed samples composited by Eq. 3 (``volume``)."""
