"""Stereo depth onboard: OpenCV's semi-global matcher on a rectified pair, its disparities
filtered against points floating in open water (StereoFilter: texture, uniqueness, left-right
consistency, speckles, occlusion edges), optionally on the pair shrunk (stereo_scale)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from abyss.config.stations import OnboardConfig


# onboard.stereo_mode (config.stations.STEREO_MODES) -> OpenCV's
SGBM_MODES = {
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


@dataclass(frozen=True)
class StereoFilter:
    """What the stereo matcher keeps, against points floating in open water: a disparity survives
    only where the block has texture (sensor noise and marine snow do not count), the best match
    beats the second by the uniqueness margin, matching right to left finds the same disparity
    (left-right consistency), its connected patch of like disparities is large (speckle
    filtering) and no disparity step lies within its block (an occlusion edge). 0 switches a
    check off; the matcher before these filters was StereoFilter(10, 100, 2, 0, 0, 0).
    bench/perception.py measures them over the default mission."""

    uniqueness_ratio: int = 15  # [%] the best cost beats the second best by this margin
    speckle_window_px: int = 400  # connected patches of like disparity smaller than this are dropped [px]
    speckle_range_px: int = 2  # neighbours within this disparity are of one patch [px]
    lr_max_diff_px: float = 1.0  # the right-to-left disparity may differ by this [px]
    min_texture: float = 0.5  # the block's intensity spread below this: no disparity (texture_of) [grey]
    # block matching smears a near surface's disparity over the far one beside it (half a block):
    # points floating off an edge. A disparity step larger than this within a block drops the
    # block's pixels [px]
    edge_step_px: float = 1.0
    # the left-right check's right-to-left match is of the pair shrunk this many times from the
    # full size, at least as much as the left-to-right one (stereo_depth)
    lr_scale: int = 2

    @staticmethod
    def of(cfg: OnboardConfig) -> StereoFilter:
        return StereoFilter(
            cfg.stereo_uniqueness_percent,
            cfg.stereo_speckle_window_px,
            cfg.stereo_speckle_range_px,
            cfg.stereo_lr_max_diff_px,
            cfg.stereo_min_texture,
            cfg.stereo_edge_step_px,
            cfg.stereo_lr_scale,
        )

    def scaled(self, scale: int) -> StereoFilter:
        """The same filter for images `scale` times smaller: windows in pixels shrunk by the
        area, disparities [px] by `scale` (a depth step or mismatch stays the same in metres)."""
        if scale == 1:
            return self
        return dataclasses.replace(
            self,
            speckle_window_px=-(-self.speckle_window_px // scale**2),
            speckle_range_px=max(1, round(self.speckle_range_px / scale)),
            lr_max_diff_px=self.lr_max_diff_px / scale,
            edge_step_px=self.edge_step_px / scale,
            lr_scale=max(1, self.lr_scale // scale),
        )


def texture_of(grey: np.ndarray, block_px: int, smoothing_px: int = 5) -> np.ndarray:
    """The standard deviation of the intensity [grey levels] over the block around each pixel, of
    the image smoothed over 5x5 px first: a sensor's pixel noise (independent from pixel to
    pixel, which the matcher pairs at random) counts for a fifth of its own, the scene's texture
    for most of its. An image shrunk by area averaging (shrunk) is smoothed already: 1, none."""
    image: np.ndarray = grey.astype(np.float32)
    if smoothing_px > 1:
        image = cv2.GaussianBlur(image, (smoothing_px, smoothing_px), 0)
    size = (block_px, block_px)
    mean = cv2.boxFilter(image, -1, size, borderType=cv2.BORDER_REFLECT)
    variance: np.ndarray = cv2.boxFilter(image * image, -1, size, borderType=cv2.BORDER_REFLECT)
    variance -= np.multiply(mean, mean, out=mean)
    np.maximum(variance, 0.0, out=variance)
    return np.sqrt(variance, out=variance)


def disparity_edges(disparity_px: np.ndarray, valid: np.ndarray, block_px: int, step_px: float) -> np.ndarray:
    """Pixels whose block holds valid disparities [px] more than `step_px` apart."""
    kernel = np.ones((block_px, block_px), np.uint8)
    none = np.float32(1e6)
    highest = cv2.dilate(np.where(valid, disparity_px, np.float32(0.0)), kernel)
    lowest = cv2.erode(np.where(valid, disparity_px, none), kernel)
    return (highest - lowest > step_px) & (lowest < none)


def shrunk(image: np.ndarray, scale: int) -> np.ndarray:
    """`image` `scale` times smaller, each pixel the mean of its block (cv2.INTER_AREA)."""
    if scale == 1:
        return image
    height_px, width_px = image.shape[:2]
    return cv2.resize(image, (width_px // scale, height_px // scale), interpolation=cv2.INTER_AREA)


def block_size_px(block_px: int, scale: int) -> int:
    """The matcher's block (odd, 3 at least) for images `scale` times smaller."""
    return max(3, round(block_px / scale) | 1)


def sgbm(disparities: int, block_px: int, kept: StereoFilter, mode: str, scale: int) -> cv2.StereoSGBM:
    """OpenCV's semi-global matcher for the pair shrunk `scale` times; `disparities`, `block_px`
    and `kept` are of the full size."""
    block_px = block_size_px(block_px, scale)
    kept = kept.scaled(scale)
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=16 * -(-disparities // (16 * scale)),  # a multiple of 16, as OpenCV's matcher needs
        blockSize=block_px,
        P1=8 * block_px**2,
        P2=32 * block_px**2,
        uniquenessRatio=kept.uniqueness_ratio,
        speckleWindowSize=kept.speckle_window_px,
        speckleRange=kept.speckle_range_px,
        disp12MaxDiff=1,
        mode=SGBM_MODES[mode],
    )


def disparity_of(matcher: cv2.StereoSGBM, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The left image's disparity [px] (OpenCV's is fixed point, 4 bits of fraction)."""
    return matcher.compute(left, right).astype(np.float32) / 16.0


def right_disparity_of(matcher: cv2.StereoSGBM, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The right image's disparity [px] at each of its pixels: the mirrored right image matched
    against the mirrored left one, mirrored back."""
    left, right = (np.ascontiguousarray(image[:, ::-1]) for image in (left, right))
    return disparity_of(matcher, right, left)[:, ::-1]


def left_right_consistent(
    disparity_px: np.ndarray, right_disparity_px: np.ndarray, ratio: int, max_diff_px: float
) -> np.ndarray:
    """Where the right image's disparity (of the pair `ratio` times smaller, in its pixels) at
    the pixel each left disparity [px] points to is found and within `max_diff_px` of it [px]."""
    height_px, width_px = right_disparity_px.shape
    # a pixel's centre x lies at (x + 0.5) / ratio - 0.5 in the shrunk image (Camera.scaled);
    # the column index broadcast along the rows, the row index along the columns, in place
    target = np.arange(disparity_px.shape[1], dtype=np.float64) - disparity_px
    target += 0.5
    target /= ratio
    target -= 0.5
    np.rint(target, out=target)
    np.clip(target, 0, width_px - 1, out=target)
    rows = np.minimum(np.arange(disparity_px.shape[0]) // ratio, height_px - 1)
    back_px = right_disparity_px[rows[:, None], target.astype(np.intp)]
    return (back_px > 0.5) & (np.abs(ratio * back_px - disparity_px) <= max_diff_px)


def stereo_depth(
    left_rgb: np.ndarray,
    right_rgb: np.ndarray,
    focal_px: float,
    baseline_m: float,
    disparities: int = 64,
    block_px: int = 9,
    kept: StereoFilter = StereoFilter(),
    mode: str = "hh",
    scale: int = 1,
) -> np.ndarray:
    """Depth [m] along the left camera's axis from a rectified pair by semi-global matching;
    0 where no disparity was found or `kept` rejects it. `scale`: the pair is matched shrunk
    this many times (shrunk) and the depth is of that size (Camera.scaled); `focal_px`,
    `disparities`, `block_px` and `kept` are of the full size (2: a tenth of the time, 13.3 cm
    on the panel's face at 4 m, the sub-pixel disparity snapped to whole pixels). `mode`
    (SGBM_MODES): the full eight-direction pass by default, the most exact (4.3 cm median on the
    panel's face at 4 m); "3way" takes half its CPU for 5.3 cm, but matches 1.4 % of a
    textureless pair's pixels. The
    five-direction "sgbm" overestimated disparity here by 0.14 px on average. The left-right
    check matches the mirrored pair (the right image, mirrored, as the left) with the same
    matcher, since this OpenCV has no cv2.ximgproc, shrunk `kept.lr_scale` times from the full
    size: at half, 110 ms per pair against 183, the map's precision and recall as at full
    (onboard.stereo_lr_scale), with `kept.lr_max_diff_px` unchanged in the left's pixels (1.5 or
    2 px let more noise through in Jerlov I: precision 0.550, 0.541 against 0.563)."""
    left, right = (shrunk(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), scale) for rgb in (left_rgb, right_rgb))
    disparity_px = disparity_of(sgbm(disparities, block_px, kept, mode, scale), left, right)
    focal_px /= scale
    full_block_px, block_px = block_px, block_size_px(block_px, scale)
    full_kept, kept = kept, kept.scaled(scale)
    valid = disparity_px > 0.5
    if kept.min_texture > 0:
        valid &= texture_of(left, block_px, 5 if scale == 1 else 1) >= kept.min_texture
    if kept.lr_max_diff_px > 0:
        ratio = kept.lr_scale  # the right-to-left pair this many times smaller than the matched one
        matcher = sgbm(disparities, full_block_px, full_kept, mode, scale * ratio)
        right_disparity_px = right_disparity_of(matcher, shrunk(left, ratio), shrunk(right, ratio))
        valid &= left_right_consistent(disparity_px, right_disparity_px, ratio, kept.lr_max_diff_px)
    if kept.edge_step_px > 0:
        valid &= ~disparity_edges(disparity_px, valid, block_px, kept.edge_step_px)
    depth_m = np.zeros_like(disparity_px)
    depth_m[valid] = focal_px * baseline_m / disparity_px[valid]
    return depth_m
