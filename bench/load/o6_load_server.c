/* open62541's side of bench/load (issue 26): an open62541 server with the nodes the load
 * clients use, so that the same clients run against it and against ours in the same run.
 * Our code, built against an open62541 built beside the project (never part of this
 * repository): bench/load/build_open62541_server.sh.
 *
 *   o6_load_server PORT
 *
 * Namespace urn:pnp:demo: object s=Demo with method s=Demo.Echo (ByteString -> the same
 * ByteString), variables s=Scalar.Int32 (Int32), s=Scalar.ByteString (ByteString, writable),
 * s=Bench.Ticker (Int64, CLOCK_MONOTONIC ns, set every 5 ms). SecurityPolicy None,
 * anonymous, sessions up to 10000. Prints "listening on opc.tcp://127.0.0.1:PORT" once
 * running; stops on SIGINT / SIGTERM. */
#include <open62541/plugin/log_stdout.h>
#include <open62541/server.h>
#include <open62541/server_config_default.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static volatile UA_Boolean running = true;
static UA_UInt16 ns = 1;

static void stopHandler(int sig) {
    (void)sig;
    running = false;
}

static UA_StatusCode echo(UA_Server* server, const UA_NodeId* sessionId, void* sessionContext,
                          const UA_NodeId* methodId, void* methodContext, const UA_NodeId* objectId,
                          void* objectContext, size_t inputSize, const UA_Variant* input,
                          size_t outputSize, UA_Variant* output) {
    (void)server, (void)sessionId, (void)sessionContext, (void)methodId, (void)methodContext;
    (void)objectId, (void)objectContext, (void)outputSize;
    if (inputSize != 1 || !UA_Variant_hasScalarType(&input[0], &UA_TYPES[UA_TYPES_BYTESTRING]))
        return UA_STATUSCODE_BADTYPEMISMATCH;
    return UA_Variant_setScalarCopy(output, input[0].data, &UA_TYPES[UA_TYPES_BYTESTRING]);
}

static void tick(UA_Server* server, void* data) {
    (void)data;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    UA_Int64 now = (UA_Int64)ts.tv_sec * 1000000000 + ts.tv_nsec;
    UA_Variant v;
    UA_Variant_setScalar(&v, &now, &UA_TYPES[UA_TYPES_INT64]);
    UA_Server_writeValue(server, UA_NODEID_STRING(ns, "Bench.Ticker"), v);
}

static void addVariable(UA_Server* server, const char* id, const char* name, const void* value,
                        const UA_DataType* type, UA_Byte access) {
    UA_VariableAttributes a = UA_VariableAttributes_default;
    UA_Variant_setScalarCopy(&a.value, value, type);
    a.dataType = type->typeId;
    a.accessLevel = access;
    a.displayName = UA_LOCALIZEDTEXT("", (char*)(uintptr_t)name);
    UA_Server_addVariableNode(
        server, UA_NODEID_STRING(ns, (char*)(uintptr_t)id), UA_NODEID_STRING(ns, "Demo"),
        UA_NODEID_NUMERIC(0, UA_NS0ID_HASCOMPONENT), UA_QUALIFIEDNAME(ns, (char*)(uintptr_t)name),
        UA_NODEID_NUMERIC(0, UA_NS0ID_BASEDATAVARIABLETYPE), a, NULL, NULL);
    UA_Variant_clear(&a.value);
}

int main(int argc, char** argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: %s PORT\n", argv[0]);
        return 2;
    }
    const int port = atoi(argv[1]);
    signal(SIGINT, stopHandler);
    signal(SIGTERM, stopHandler);
    UA_Server* server = UA_Server_new();
    UA_ServerConfig* config = UA_Server_getConfig(server);
    UA_ServerConfig_setMinimal(config, (UA_UInt16)port, NULL);
    config->maxSessions = 10000;
    config->maxSecureChannels = 10000;
    ns = UA_Server_addNamespace(server, "urn:pnp:demo");

    UA_ObjectAttributes oa = UA_ObjectAttributes_default;
    oa.displayName = UA_LOCALIZEDTEXT("", "Demo");
    UA_Server_addObjectNode(server, UA_NODEID_STRING(ns, "Demo"),
                            UA_NODEID_NUMERIC(0, UA_NS0ID_OBJECTSFOLDER),
                            UA_NODEID_NUMERIC(0, UA_NS0ID_ORGANIZES), UA_QUALIFIEDNAME(ns, "Demo"),
                            UA_NODEID_NUMERIC(0, UA_NS0ID_BASEOBJECTTYPE), oa, NULL, NULL);

    UA_Argument in, out;
    UA_Argument_init(&in);
    in.name = UA_STRING("In");
    in.dataType = UA_TYPES[UA_TYPES_BYTESTRING].typeId;
    in.valueRank = UA_VALUERANK_SCALAR;
    UA_Argument_init(&out);
    out.name = UA_STRING("Out");
    out.dataType = UA_TYPES[UA_TYPES_BYTESTRING].typeId;
    out.valueRank = UA_VALUERANK_SCALAR;
    UA_MethodAttributes ma = UA_MethodAttributes_default;
    ma.displayName = UA_LOCALIZEDTEXT("", "Echo");
    ma.executable = true;
    ma.userExecutable = true;
    UA_Server_addMethodNode(server, UA_NODEID_STRING(ns, "Demo.Echo"), UA_NODEID_STRING(ns, "Demo"),
                            UA_NODEID_NUMERIC(0, UA_NS0ID_HASCOMPONENT),
                            UA_QUALIFIEDNAME(ns, "Echo"), ma, echo, 1, &in, 1, &out, NULL, NULL);

    const UA_Int32 int32 = 42;
    const UA_ByteString bytes = UA_BYTESTRING("pnp");
    const UA_Int64 zero = 0;
    const UA_Byte rw = UA_ACCESSLEVELMASK_READ | UA_ACCESSLEVELMASK_WRITE;
    addVariable(server, "Scalar.Int32", "Int32", &int32, &UA_TYPES[UA_TYPES_INT32],
                UA_ACCESSLEVELMASK_READ);
    addVariable(server, "Scalar.ByteString", "ByteString", &bytes, &UA_TYPES[UA_TYPES_BYTESTRING],
                rw);
    addVariable(server, "Bench.Ticker", "Ticker", &zero, &UA_TYPES[UA_TYPES_INT64],
                UA_ACCESSLEVELMASK_READ);
    UA_Server_addRepeatedCallback(server, tick, NULL, 5.0, NULL);

    UA_StatusCode rc = UA_Server_run_startup(server);
    if (rc != UA_STATUSCODE_GOOD) {
        fprintf(stderr, "startup: %s\n", UA_StatusCode_name(rc));
        UA_Server_delete(server);
        return 1;
    }
    printf("listening on opc.tcp://127.0.0.1:%d\n", port);
    fflush(stdout);
    while (running) UA_Server_run_iterate(server, true);
    UA_Server_run_shutdown(server);
    UA_Server_delete(server);
    return 0;
}
