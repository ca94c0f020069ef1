"""Contact sheet of simulated frames with their ground-truth vertices drawn on top."""
import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.sim.scene import FloatArray


def thumbnail(image_bgr: npt.NDArray[np.uint8], truth: dict[str, object],
              target_centre_m: FloatArray, width_px: int = 426) -> npt.NDArray[np.uint8]:
    """
    One downscaled frame: visible target vertices as green rings, hidden ones as red dots.

    :param truth: the frame's gt.json entry (``frames[k]``).
    :param target_centre_m: (3,) world point whose distance is printed, m.
    """
    h, w = image_bgr.shape[:2]
    s = width_px / w
    small = cv2.resize(image_bgr, (width_px, int(round(h * s))), interpolation=cv2.INTER_AREA)
    for tgt in truth['targets']:  # type: ignore[attr-defined]
        for p, vis in zip(tgt['vertices_px'], tgt['vertex_visible']):
            if p is None:
                continue
            c = (int(round(p[0] * s)), int(round(p[1] * s)))
            if vis:
                cv2.circle(small, c, 4, (0, 255, 0), 1, cv2.LINE_AA)
            elif 0 <= c[0] < small.shape[1] and 0 <= c[1] < small.shape[0]:
                cv2.circle(small, c, 2, (0, 0, 255), -1, cv2.LINE_AA)
    T = np.array(truth['T_world_cam'])
    dist = float(np.linalg.norm(T[:3, 3] - target_centre_m))
    label = f'#{truth["index"]}  {dist:.1f} m'
    if truth['pure_rotation']:
        label += '  rotation'
    if truth['motion_blur_px'] > 3.0:  # type: ignore[operator]
        label += f'  blur {truth["motion_blur_px"]:.0f} px'
    (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
    cv2.rectangle(small, (0, 0), (tw + 10, th + 10), (0, 0, 0), -1)
    cv2.putText(small, label, (5, th + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                cv2.LINE_AA)
    return small


def sheet(thumbnails: list[npt.NDArray[np.uint8]], columns: int = 3,
          title: str = '') -> npt.NDArray[np.uint8]:
    """Tile equally sized thumbnails row by row, with an optional title strip on top."""
    th, tw = thumbnails[0].shape[:2]
    rows = (len(thumbnails) + columns - 1) // columns
    out = np.full((rows * (th + 4) + 4 + (28 if title else 0), columns * (tw + 4) + 4, 3), 255,
                  np.uint8)
    top = 28 if title else 0
    if title:
        cv2.putText(out, title, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                    cv2.LINE_AA)
    for i, img in enumerate(thumbnails):
        r, c = divmod(i, columns)
        y, x = top + 4 + r * (th + 4), 4 + c * (tw + 4)
        out[y:y + th, x:x + tw] = img
    return out
