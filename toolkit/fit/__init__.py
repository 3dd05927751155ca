"""``trioman fit``: a person's video -> a subject folder, with the Anny body fitted to the whole sequence."""
