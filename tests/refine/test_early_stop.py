"""The early-stop rule reads the mean of every view's latest loss."""

from lumos3d_cli.refine.early_stop import EarlyStop


def test_waits_until_every_view_has_a_loss():
    stop = EarlyStop(views=3, patience=1, tolerance=0.0)
    for _ in range(5):
        stop.update({0: 1.0})
    assert not stop.should_stop


def test_stops_when_the_loss_stays_flat():
    stop = EarlyStop(views=2, patience=3, tolerance=0.01)
    stop.update({0: 1.0, 1: 1.0})
    for step in range(3):
        assert not stop.should_stop
        stop.update({step % 2: 0.999})  # under the tolerance
    assert stop.should_stop


def test_keeps_going_while_the_loss_falls():
    stop = EarlyStop(views=2, patience=2, tolerance=0.01)
    loss = 1.0
    for step in range(50):
        loss *= 0.98
        stop.update({step % 2: loss})
    assert not stop.should_stop


def test_a_noisy_view_order_does_not_trigger_it():
    """The raw losses jump between an easy and a hard view; their running mean keeps falling."""
    stop = EarlyStop(views=2, patience=2, tolerance=0.005)
    for step in range(40):
        scale = 1 - 0.02 * step
        stop.update({0: 0.1 * scale} if step % 2 else {1: 1.0 * scale})
    assert not stop.should_stop


def test_a_restart_gives_the_changed_scene_its_patience_again():
    """After a densification the loss is judged afresh: a flat loss stops only `patience` steps
    after the restart, even if it had been flat for longer before."""
    stop = EarlyStop(views=1, patience=3, tolerance=0.01)
    for _ in range(3):
        stop.update({0: 1.0})
    assert stop.steps_since_mark == 2 and not stop.should_stop
    stop.restart()
    for step in range(3):
        stop.update({0: 1.0})
        assert not stop.should_stop, step  # the first update sets the new mark
    stop.update({0: 1.0})
    assert stop.should_stop
