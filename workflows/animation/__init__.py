"""The animation stage: a video's estimates -> per-track animations (``smplik scene animate``), and their edits.

* :mod:`.clips`: reading an estimator's frames as a clip, the :class:`~.clips.Animation` records, cleaning and
  keyframes per track (:func:`~.clips.animation_from_clip`; the steps are in that module's docstring);
* :mod:`.clean`: cleaning methods (smoothing, glitch repair, foot locks; the foot-contact detector itself is
  :mod:`smplik.contacts`); :mod:`.denoise`: the adaptive per-channel smoother;
* :mod:`.files`: ``animation.json`` (read, write, a frame as a scene); :mod:`.run`: file in, files out
  (:func:`~.run.animate_file`, :func:`~.run.export_animation`);
* :mod:`.preview`: preview videos; :mod:`.keyframe_edit`: ``scene edit-keyframe``; :mod:`.cli`: the commands.

Nothing is imported here, so that ``smplik scene --help`` (which loads :mod:`.cli`) stays light.
"""
