"""``trioman view``: an exported avatar in the browser, posed live by the runtime (numpy + onnxruntime).

    config     what the viewer serves and how (host, port, playback rate), the command's options (standard library)
    posing     the pose a viewer shows (motion frame, rest pose, per-group bends) and the splat arrays
               that changed since the last update (numpy only)
    server     the viser server: splats, controls, playback, the URL, a busy port refused
    cameras    a subject's training cameras as frustums; a click shows the real frame beside the render
    augmented  an augment output: source frame, candidates, refined frame, Examiner scores, the kept one

viser (``pip install 'trioman[viewer]'``) is imported by ``server``, ``cameras`` and ``augmented`` only;
``posing`` needs numpy alone. Nothing here imports torch.
"""
