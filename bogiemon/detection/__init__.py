"""Pure numerical core: accelerations in, per-window fault indicators out (numpy/scipy only).

No I/O, threads, logging or clocks live here; times are data passed in by the caller.
"""

from bogiemon.detection.channel_stats import ChannelStats
from bogiemon.detection.conditioning import StreamingSOS, butter_sos
from bogiemon.detection.indicators import IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.detection.kinematics import PAPER_LAYOUT, BogieGeometry, Corner, from_modal, to_modal
from bogiemon.detection.xcorr import StreamingCrossCorrelator, WindowCorrelations, xcorr_direct

__all__ = [
    "PAPER_LAYOUT",
    "BogieGeometry",
    "ChannelStats",
    "Corner",
    "IndicatorStream",
    "ProcessingSettings",
    "StreamingCrossCorrelator",
    "StreamingSOS",
    "WindowCorrelations",
    "WindowIndicators",
    "butter_sos",
    "from_modal",
    "to_modal",
    "xcorr_direct",
]
