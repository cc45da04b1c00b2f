//! `mapmerge eval make-merge-cases` and `mapmerge eval invalid-merge` (issue 6, part 5).
