"""The sister study (issue 33): both bogies of a wagon, each the other's reference."""
