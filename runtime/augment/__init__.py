"""Offline augmentation (paper 3.2.3-3.2.6): pseudo-GT frames for a subject, without torch.

For each source frame T of a subject (default: its train split):

    generate  the Generator draws ``per_frame`` candidates (pose + camera perturbation) with a seed
              derived from (seed, T's index in the subject), so a resumed or limited run draws the
              same candidates; the real frame I^T is read
    render    the avatar at each candidate's pose and camera (numpy splat renderer, frame T's K, the
              subject's size and background): the coarse frame I_c and its alpha
    normal    the subject's body at the candidate's pose and camera: the normal map I_g (only when the
              Refiner is conditioned on geometry)
    refine    Refiner(I_c, reference I^T, normal I_g) -> I_r (all candidates in one batch)
    examine   Examiner score of every I_r against I^T; the higher-scoring candidate is kept, and
              dropped when its score < threshold. Without an Examiner every candidate is kept.
    write     the kept frames' images and masks, then the frame's record (all atomic)

The pseudo-GT mask is the avatar render's alpha A at the candidate's pose and camera, and the
pseudo-GT image is the refined frame over the subject's background through that mask,
A * I_r + (1 - A) * background, so image and mask agree as in any subject (the training loop
composites images over random backgrounds with the mask); with ``keep_carried`` the real pixels carried
to the draw stay and I_r is taken only where nothing was carried. The output
folder is a subject folder (docs/formats.md "Augmented frames") plus ``records/``, ``augment.json``
and the score histogram ``scores.png``. A frame is done when its record exists: an interrupted run
leaves only complete frames, and ``resume=True`` skips them and ends with the same files as an
uninterrupted run (``subject.json``, ``frames.npz`` and ``augment.json`` are assembled from the
records at the end; only the timings differ).

Sharded (``shard``, runtime/shards.py): shard I of N does the source frames at positions p % N == I of
the selection into its own folder ``out/shards/I-of-N`` (a resumable run like any other) and records
itself; ``merge=True`` checks every shard (finished, same settings), moves their frames and records
into ``out`` and assembles it as above: the files of a one-process run, timings aside.

The package, in the order a run goes:

    run        ``augment()``: the arguments checked, the inputs loaded, the loop over the source frames
    checks     the arguments and the output folder, before any work (what ``overwrite`` may remove)
    settings   what the run records about its inputs, and what a resume must share with the run it continues
    step       one source frame: the draws, the shared augmentation step, the kept frames' files, its record
    records    a frame's record read back (resume) and checked in full (merge)
    merge      the shards' frames and records moved into the output
    assemble   the pseudo-GT subject, the histogram and augment.json from the records
    histogram  scores.png
    layout     the output's names, format and version, the timed stages, the JSON text
"""

from trioman.runtime.augment.histogram import draw_histogram
from trioman.runtime.augment.layout import AUGMENT_FORMAT, AUGMENT_JSON, AUGMENT_VERSION, HISTOGRAM_PNG, RECORDS_DIR, STAGES
from trioman.runtime.augment.records import check_record
from trioman.runtime.augment.run import augment
from trioman.runtime.augment.step import frame_seed
from trioman.runtime.formats.subject import WEIGHTS_DIR

__all__ = ["AUGMENT_JSON", "RECORDS_DIR", "WEIGHTS_DIR", "HISTOGRAM_PNG", "STAGES", "augment", "frame_seed", "draw_histogram",
           "check_record", "AUGMENT_FORMAT", "AUGMENT_VERSION"]
