"""A scripted partner at a `cogail collect` table: one person drives one agent, the task's scripted team the other.

    cogail collect --task examples.table_carry:TASK          # serves the page, prints the links
    python examples/collect_partner.py --url http://127.0.0.1:8766 --task examples.table_carry:TASK --seat robot
    # then open the human seat's link in a browser and play

Each episode, the partner reads the episode's start (``init``) from the page's view, plays the team from it in a copy
of the episode (``collect.scripted_actions``: the team's own moves, open loop, as if its partner followed the script)
and sends the action of the step each frame shows, through the page's protocol (``collect.Client``), as a browser
would. Its episodes are recorded like any other, with ``robot_input`` (or ``human_input``) = ``controller``. A task
without a scripted team gets seeded random choices. ``--code``: the seat's join code on a table open to the network.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import threading

import numpy as np


@contextlib.contextmanager
def seat_kept(client, episode, every: float = 0.2):
    """While the body runs (the team's plan computed, its first time compiled: seconds on a busy CPU), an idle
    command every ``every`` seconds from a thread of its own, as an open page sends its frames' commands, so that the
    table does not drop the seat as one not heard from (``cogail collect --leave``, 5 s by default)."""
    done, errors = threading.Event(), []

    def beat():
        while not done.wait(every):
            try:
                client.send(episode=episode)
            except Exception as e:  # noqa: BLE001 -- raised in the caller's thread once the body is done
                errors.append(e)
                return

    t = threading.Thread(target=beat, daemon=True)
    t.start()
    try:
        yield
    finally:
        done.set()
        t.join()
    if errors:
        raise errors[0]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--url", required=True, help="the table, e.g. http://127.0.0.1:8766")
    p.add_argument("--task", required=True, help="the table's task (as given to cogail collect)")
    p.add_argument("--seat", choices=("human", "robot"), default="robot")
    p.add_argument("--code", default=None, help="the seat's join code (a table open to the network)")
    p.add_argument("--episodes", type=int, default=0, help="stop after N episodes (default: until Ctrl-C)")
    a = p.parse_args(argv)

    import cogail_envs
    from cogail_jax.apps import collect

    env = cogail_envs.make_env(a.task)
    client = collect.Client(a.url)
    try:
        client.join(a.seat, a.code)
    except collect.Refused as e:
        print(f"collect_partner: the table at {a.url} refused the {a.seat} seat: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"collect_partner: cannot reach a table at {a.url} ({getattr(e, 'reason', e)}): start `cogail collect "
              f"--task {a.task}` first, or pass the --url it prints", file=sys.stderr)
        return 2
    print(f"driving the {a.seat} agent of {env.name} at {a.url}; Ctrl-C to stop", flush=True)
    script, episode, played = None, None, 0
    try:
        v = client.view()
        while not a.episodes or played < a.episodes:
            if v["episode"] != episode:  # a new episode: the team's plan from its start
                if episode is not None:
                    played += 1
                episode = v["episode"]
                with seat_kept(client, episode):
                    ah, ar = collect.scripted_actions(env, np.asarray(v["init"], np.float32), seed=episode,
                                                      steps=v["max_steps"])
                script = ah if a.seat == "human" else ar
            if v["status"] in ("ready", "running"):
                client.send(action=script[min(v["t"], len(script) - 1)], episode=episode)
            else:
                client.send(episode=episode)  # keep the seat (an idle command)
            v = client.view(v["frame_id"])
    except KeyboardInterrupt:
        pass
    except collect.Refused as e:  # 403: the table dropped the seat (e.g. not heard from for its --leave seconds)
        print(f"collect_partner: the table at {a.url} dropped the {a.seat} seat ({e}): run this script again"
              if e.status == 403 else f"collect_partner: the table at {a.url} refused a command: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"collect_partner: the table at {a.url} stopped answering ({getattr(e, 'reason', e)}): start "
              f"`cogail collect --task {a.task}` again, then this script", file=sys.stderr)
        return 2
    finally:
        with contextlib.suppress(collect.Refused, OSError):
            client.leave()
    return 0


if __name__ == "__main__":
    sys.exit(main())
