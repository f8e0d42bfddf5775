"""Frames and ground truth in: OTB / VOT folders, videos, the synthetic default and its failure scenarios."""
