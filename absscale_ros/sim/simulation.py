"""
One simulated video: scene + camera + handheld path + effects, frame by frame with its truth.

No ROS here: ``absscale_ros.tools.simulate`` turns the frames into messages and a bag.
"""
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
import numpy.typing as npt

from absscale_ros.sim import camera as simcam
from absscale_ros.sim import effects, groundtruth, render, scenes, trajectory

START_STAMP_NS = 1_700_000_000 * 10 ** 9  # fixed, so the same seed gives the same bytes
EFFECTS = {'indoor_paper': effects.EffectsConfig(exposure_s=0.008, read_noise_dn=1.6,
                                                 shot_noise=0.05, brightness_target=112.0),
           'outdoor_cube': effects.EffectsConfig(exposure_s=0.003, read_noise_dn=1.0,
                                                 shot_noise=0.03, brightness_target=122.0)}


@dataclass(frozen=True)
class SimConfig:
    """What to simulate."""

    scene: str
    seed: int
    frames: int = 300
    width: int = 1280
    height: int = 720
    fps: float = 30.0
    variant: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        scenes.check_name(self.scene)
        if self.frames < 1:
            raise ValueError(f'frames must be >= 1, got {self.frames}')
        if self.width % render.BLOCK or self.height % render.BLOCK or self.width < 64:
            raise ValueError(f'size must be multiples of {render.BLOCK} px, got '
                             f'{self.width}x{self.height}')


@dataclass(frozen=True)
class SimFrame:
    """One image with its ``frames[k]`` ground-truth entry."""

    index: int
    stamp_ns: int
    image_bgr: npt.NDArray[np.uint8]
    truth: dict[str, object]
    data: bytes = b''  # what the ``encode`` callback made of the image


class Simulation:
    """Deterministic for a given config: the same frames, bytes and truth every time."""

    def __init__(self, cfg: SimConfig) -> None:
        self.cfg = cfg
        rngs = scenes.streams(cfg.seed)
        self.scene = scenes.build_scene(cfg.scene, cfg.seed, cfg.variant)
        self.camera = simcam.make_camera(rngs['camera'], cfg.width, cfg.height)
        self.trajectory = trajectory.make(self.scene, cfg.frames / cfg.fps, rngs['trajectory'])
        self.renderer = render.Renderer(self.scene, self.camera)
        self._effects_cfg = EFFECTS[cfg.scene]
        self._effects = effects.CameraEffects(self.camera, self._effects_cfg, rngs['effects'])
        self.rotation_segments = self.trajectory.rotation_frames(cfg.fps, cfg.frames)
        self._in_rotation = np.zeros(cfg.frames, bool)
        for first, last in self.rotation_segments:
            self._in_rotation[first:last + 1] = True

    def stamp_ns(self, index: int) -> int:
        return START_STAMP_NS + int(round(index * 1e9 / self.cfg.fps))

    def header(self, bag: dict[str, object]) -> dict[str, object]:
        """Everything in gt.json except ``frames`` (``bag`` describes topics and encoding)."""
        sc = self.scene
        return {'schema': groundtruth.SCHEMA, 'schema_version': groundtruth.SCHEMA_VERSION,
                'sim_version': scenes.SIM_VERSION,
                'scene': {'name': sc.name, 'seed': sc.seed, 'variant': sc.variant},
                'bag': {**bag, 'fps': self.cfg.fps, 'frame_count': self.cfg.frames},
                'camera': groundtruth.camera_json(self.camera),
                'light': {'direction_world': sc.light_dir_world.tolist(), 'ambient': sc.ambient,
                          'direct': sc.direct},
                'targets': [groundtruth.target_json(t, i) for i, t in enumerate(sc.targets)],
                'distractors': sc.distractors, 'point_pairs': sc.point_pairs,
                'pure_rotation_segments': self.rotation_segments}

    def frames(self, encode: Callable[[npt.NDArray[np.uint8], int], bytes] | None = None,
               pipelined: bool = True) -> Iterator[SimFrame]:
        """
        Render, blur, expose every frame in order, with its truth.

        :param encode: optional ``(image_bgr, stamp_ns) -> bytes`` (e.g. JPEG + serialise),
            run in the finishing thread; its result is ``SimFrame.data``.
        :param pipelined: finish frame k (effects, outlines, encode) in a second thread while
            frame k + 1 renders. The output is identical either way: the finishing steps run
            in frame order in one thread and own all the effect state.
        """
        if not pipelined:
            for k in range(self.cfg.frames):
                yield self._finish(self._render(k), encode)
            return
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = None
            for k in range(self.cfg.frames):
                rendered = self._render(k)
                if pending is not None:
                    yield pending.result()
                pending = pool.submit(self._finish, rendered, encode)
            if pending is not None:
                yield pending.result()

    def _render(self, k: int) -> '_Rendered':
        t = k / self.cfg.fps
        T = self.trajectory.pose(t)
        frame = self.renderer.render(T)
        half = 0.5 * self._effects_cfg.exposure_s
        visibility = [groundtruth.vertex_visibility(self.renderer, T, tg.vertices_world_m)
                      for tg in self.scene.targets]
        return _Rendered(k, t, T, frame, self.trajectory.pose(t - half),
                         self.trajectory.pose(t + half), visibility)

    def _finish(self, r: '_Rendered',
                encode: Callable[[npt.NDArray[np.uint8], int], bytes] | None) -> SimFrame:
        colour, blur_px = self._effects.motion_blur(r.frame.colour, r.frame.grid_points_world_m,
                                                    r.T_start, r.T_end)
        image, gain = self._effects.expose(colour, r.t_s)
        stamp = self.stamp_ns(r.index)
        truth = {'index': r.index, 'stamp_ns': stamp, 'T_world_cam': r.T.tolist(),
                 'pure_rotation': bool(self._in_rotation[r.index]),
                 'motion_blur_px': round(blur_px, 3), 'exposure_gain': round(gain, 5),
                 'targets': groundtruth.frame_targets(self.renderer, r.frame, r.T,
                                                      r.visibility)}
        data = encode(image, stamp) if encode is not None else b''
        return SimFrame(r.index, stamp, image, truth, data)


@dataclass(frozen=True)
class _Rendered:
    """A frame between rendering (main thread) and finishing (effects thread)."""

    index: int
    t_s: float
    T: npt.NDArray[np.float64]
    frame: render.Frame
    T_start: npt.NDArray[np.float64]
    T_end: npt.NDArray[np.float64]
    visibility: list[tuple[npt.NDArray[np.float64], list[bool]]]
