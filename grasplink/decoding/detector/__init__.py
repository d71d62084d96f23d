"""The contact detector's parts (`contacts.ContactDetector` composes them).

- `hinges`: the hinge (kink) bank - slope jumps at several scales, their local maxima,
  timed coarse to fine: the ridge contacts of a clean signal;
- `tail_kinks`: which kinks with no rise after them are ridges on a pulse's falling tail
  (the kink bank's rescue of what its rise check drops);
- `noise_floor`: the noise each hinge scale is judged against, block by block;
- `watch`: the pulse watcher - the level after each contact, told a pulse or a step;
- `step_probe`: small steps the kink bank misses (a difference of means);
- `pulse_probe`: ridge pulses the kink bank is blind to in heavy noise (the size of a
  rise);
- `series`: the buffers they share (recent samples, arrays appended in place) and
  `events`: what they tell and the contacts told so far.
"""
