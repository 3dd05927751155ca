"""The names of what a pseudo-GT frame holds, its mask and its stages (runtime/pseudo_gt.py), standard-library only:
configs whose options a command's parser is built from name them without importing numpy."""

# coarse: the avatar's render; aligned: the render with real pixels carried through the body mesh where
# known; refined / examined: the Refiner's output (examined: the Examiner's pick); truth: the subject's own
# renderer at the draw (synthetic subjects: the ceiling a perfect Refiner would reach); truth_seen: the truth
# only where a training frame saw the surface (where real pixels were carried), ``unknown_weight`` elsewhere on
# the body (the ceiling of pseudo-GT made from what the capture holds, with nothing invented).
KINDS = ("coarse", "aligned", "refined", "examined", "truth", "truth_seen")
# carried: the body mesh's coverage plus the source mask carried beyond it (runtime/aligned.py);
# alpha: the render's own alpha (the paper's; teaches whatever the avatar renders off the body).
MASKS = ("carried", "alpha")
STAGES = ("generate", "render", "align", "normal", "refine", "examine")
