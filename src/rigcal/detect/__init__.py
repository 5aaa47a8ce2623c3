"""Board detectors: one per (modality, target). Each returns a BoardDetection or an explicit
DetectionFailure with its reason - never a bare bool."""

from rigcal.detect.result import BoardDetection, DetectionFailure, DetectionResult

__all__ = ["BoardDetection", "DetectionFailure", "DetectionResult"]
