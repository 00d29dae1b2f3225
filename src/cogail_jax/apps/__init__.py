"""The applications: the ``cogail`` CLI, the training and evaluation host loops, play, video, report, bench."""
