"""The animation stage: a video's estimates -> per-track animations (``smplik scene animate``), and their edits.

* :mod:`.clips`: reading an estimator's frames as a clip, the :class:`Animation` records, cleaning and keyframes
  per track (:func:`animation_from_clip`; the steps are in that module's docstring);
* :mod:`.clean`: cleaning methods (smoothing, glitch repair, foot locks; the foot-contact detector itself is
  :mod:`smplik.contacts`); :mod:`.denoise`: the adaptive per-channel smoother;
* :mod:`.files`: ``animation.json`` (read, write, a frame as a scene); :mod:`.run`: file in, files out
  (:func:`animate_file`, :func:`export_animation`);
* :mod:`.preview`: preview videos; :mod:`.keyframe_edit`: ``scene edit-keyframe``; :mod:`.cli`: the commands.
"""

from workflows.animation.clips import (
    ASSUMED_FPS,
    KNOWN_FPS,
    MAX_FRAMES,
    NEAR_ORTHOGRAPHIC_FOV_DEG,
    NORMAL_FOV_DEG,
    AnimateConfig,
    Animation,
    AnimationError,
    AnimationTrack,
    Clip,
    DepthChange,
    Keyframe,
    Progress,
    TrackMotion,
    animation_from_clip,
    axis_angle_to_local,
    camera_clean,
    camera_fov,
    check_track,
    clean_track,
    clip_length,
    frames_present,
    has_world_trajectory,
    interpolate_poses,
    joints_of,
    keyframe_threshold,
    parse_frames,
    read_clip,
    read_folder_clip,
    realistic_depth,
    repair_frames,
    rest_joints,
    select_keyframes,
    stored_fps,
)
from workflows.animation.files import (
    AnimationFileError,
    animation_from_dict,
    animation_to_dict,
    load_animation,
    save_animation,
    scene_of,
)
from workflows.animation.run import (
    AnimateOutputs,
    animate_file,
    export_animation,
)

__all__ = [
    "ASSUMED_FPS", "AnimateConfig", "AnimateOutputs", "Animation", "AnimationError", "AnimationFileError",
    "AnimationTrack", "Clip", "DepthChange", "KNOWN_FPS", "Keyframe", "MAX_FRAMES", "NEAR_ORTHOGRAPHIC_FOV_DEG",
    "NORMAL_FOV_DEG", "Progress", "TrackMotion", "animate_file", "animation_from_clip", "animation_from_dict",
    "animation_to_dict", "axis_angle_to_local", "camera_clean", "camera_fov", "check_track", "clean_track",
    "clip_length", "export_animation", "frames_present", "has_world_trajectory", "interpolate_poses",
    "joints_of", "keyframe_threshold", "load_animation", "parse_frames", "read_clip", "read_folder_clip",
    "realistic_depth", "repair_frames", "rest_joints", "save_animation", "scene_of", "select_keyframes",
    "stored_fps",
]
