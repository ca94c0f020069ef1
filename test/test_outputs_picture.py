"""`run.png`'s drawing process: it reports why it drew nothing, and never outlives the run."""
from absscale_ros import outputs


def test_a_drawing_that_never_ends_is_killed_and_said_so() -> None:
    picture = outputs.Picture()  # never given its arguments: it waits on stdin for ever
    try:
        result = picture.wait(timeout_s=1.0)
        assert result == {'skipped': 'drawing took longer than 1 s'}
        assert picture._proc.returncode is not None  # gone, not left behind
    finally:
        picture.close()


def test_a_drawing_that_fails_says_why() -> None:
    picture = outputs.Picture()
    try:
        picture.draw({'quats': None, 'no_such_argument': 1})
        result = picture.wait(timeout_s=120.0)
        assert 'drawing failed' in result['skipped']
        assert 'no_such_argument' in result['skipped']
    finally:
        picture.close()
