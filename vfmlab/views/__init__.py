"""What the command line shows: rich tables and lines of text built from what the stages return.

The stages compute and return data; these views turn it into renderables; ``vfmlab/cli`` prints them. Kept apart
from both so that a notebook or the live panel can show the same tables.
"""
