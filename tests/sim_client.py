"""A simulation_interfaces client for the tests: what a tool written against ROS 2's standard sends, over DDS.

Non-idempotent requests (spawn, delete, step, state changes) are sent once; so that their replies cannot be
lost to Fast DDS's reply-matching race (see ``ros_probe.Probe.call``), each client is first warmed up with a
request of the same type that is refused without any effect (:data:`HARMLESS`).
"""

from __future__ import annotations

from simulation_interfaces.msg import Result, SimulationState
from simulation_interfaces.srv import (
    DeleteEntity,
    GetAvailableWorlds,
    GetCurrentWorld,
    GetEntities,
    GetEntitiesStates,
    GetEntityBounds,
    GetEntityInfo,
    GetEntityState,
    GetNamedPoseBounds,
    GetNamedPoses,
    GetSimulationState,
    GetSimulatorFeatures,
    GetSpawnables,
    LoadWorld,
    ResetSimulation,
    SetEntityInfo,
    SetEntityState,
    SetSimulationState,
    SpawnEntities,
    SpawnEntity,
    StepSimulation,
    UnloadWorld,
)

NODE = "/cgp_sim"
OK = Result.RESULT_OK

#: a request of each non-idempotent type that the simulator refuses without changing anything
HARMLESS = {
    SpawnEntity: lambda: SpawnEntity.Request(),  # no resource: NO_RESOURCE
    DeleteEntity: lambda: DeleteEntity.Request(entity="no such entity"),  # NOT_FOUND
    SetEntityState: lambda: SetEntityState.Request(entity="no such entity"),  # NOT_FOUND
    StepSimulation: lambda: StepSimulation.Request(steps=0),  # steps must be at least 1
    SetSimulationState: lambda: SetSimulationState.Request(state=SimulationState(state=200)),  # unknown state
    ResetSimulation: lambda: ResetSimulation.Request(scope=8),  # unknown scope bit
    LoadWorld: lambda: LoadWorld.Request(),  # no resource: NO_RESOURCE
    SpawnEntities: lambda: SpawnEntities.Request(),  # an empty batch: OPERATION_FAILED
    SetEntityInfo: lambda: SetEntityInfo.Request(entity="no such entity"),  # NOT_FOUND
}
SERVICE_NAMES = {
    GetSimulatorFeatures: "get_simulator_features", SpawnEntity: "spawn_entity", DeleteEntity: "delete_entity",
    GetEntities: "get_entities", GetEntitiesStates: "get_entities_states", GetEntityState: "get_entity_state",
    SetEntityState: "set_entity_state", ResetSimulation: "reset_simulation",
    GetSimulationState: "get_simulation_state", SetSimulationState: "set_simulation_state",
    StepSimulation: "step_simulation", GetAvailableWorlds: "get_available_worlds", LoadWorld: "load_world",
    UnloadWorld: "unload_world", GetCurrentWorld: "get_current_world", GetSpawnables: "get_spawnables",
    SpawnEntities: "spawn_entities", GetEntityInfo: "get_entity_info", SetEntityInfo: "set_entity_info",
    GetEntityBounds: "get_entity_bounds", GetNamedPoses: "get_named_poses", GetNamedPoseBounds: "get_named_pose_bounds",
}


class SimClient:
    def __init__(self, probe, node: str = NODE):
        self.probe = probe
        self.node = node
        self._warm: set = set()

    def call(self, srv_type, request=None, timeout: float = 30.0):
        """The response to ``request`` (default: the type's empty request)."""
        name = f"{self.node}/{SERVICE_NAMES[srv_type]}"
        request = srv_type.Request() if request is None else request
        if srv_type not in HARMLESS:
            return self.probe.call(srv_type, name, request, timeout)
        if srv_type not in self._warm:
            refused = self.probe.call(srv_type, name, HARMLESS[srv_type](), timeout)
            assert refused.result.result != OK, refused
            self._warm.add(srv_type)
        return self.probe.call(srv_type, name, request, timeout, idempotent=False)

    # ---- shorthands ---------------------------------------------------------------------------------------

    def spawn(self, name: str, resource: str = "", *, position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
              uri: str = "", allow_renaming: bool = False, frame: str = "", namespace: str = ""):
        request = SpawnEntity.Request(name=name, allow_renaming=allow_renaming, uri=uri, resource_string=resource,
                                      entity_namespace=namespace)
        request.initial_pose.header.frame_id = frame
        p, q = request.initial_pose.pose.position, request.initial_pose.pose.orientation
        p.x, p.y, p.z = map(float, position)
        q.x, q.y, q.z, q.w = map(float, orientation)
        return self.call(SpawnEntity, request)

    def delete(self, name: str):
        return self.call(DeleteEntity, DeleteEntity.Request(entity=name))

    def names(self, pattern: str = "") -> list[str]:
        request = GetEntities.Request()
        request.filters.filter = pattern
        response = self.call(GetEntities, request)
        assert response.result.result == OK, response.result
        return list(response.entities)

    def state(self, name: str):
        return self.call(GetEntityState, GetEntityState.Request(entity=name))

    def set_state(self, name: str, position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0), linear=(0, 0, 0),
                  angular=(0, 0, 0), frame: str = ""):
        request = SetEntityState.Request(entity=name)
        request.state.header.frame_id = frame
        p, q = request.state.pose.position, request.state.pose.orientation
        p.x, p.y, p.z = map(float, position)
        q.x, q.y, q.z, q.w = map(float, orientation)
        t = request.state.twist
        t.linear.x, t.linear.y, t.linear.z = map(float, linear)
        t.angular.x, t.angular.y, t.angular.z = map(float, angular)
        return self.call(SetEntityState, request)

    def simulation_state(self) -> int:
        response = self.call(GetSimulationState)
        assert response.result.result == OK
        return response.state.state

    def set_simulation_state(self, state: int):
        return self.call(SetSimulationState, SetSimulationState.Request(state=SimulationState(state=state)))

    def step(self, steps: int, timeout: float = 60.0):
        return self.call(StepSimulation, StepSimulation.Request(steps=steps), timeout)

    def reset(self, scope: int):
        return self.call(ResetSimulation, ResetSimulation.Request(scope=scope))


def vec(v) -> list[float]:
    return [v.x, v.y, v.z]


def quat(q) -> list[float]:
    return [q.x, q.y, q.z, q.w]
