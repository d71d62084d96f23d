"""The numpy code the decoders' compiled kernels replaced, recovered from git history (commit
0858d90, the last numpy version: `git show 0858d90:grasplink/decoding/contacts.py`
and `tracker.py`), kept here as the reference the kernels are checked against, in the same
process on the same inputs: `contacts` (the detector), `filters` (its streaming filter),
`tracker` (the branching, pruning and posterior). `compare` derives how far a kernel's
numbers may be from the reference's from the arithmetic between them.

Not runtime code: nothing under grasplink/ imports it."""
