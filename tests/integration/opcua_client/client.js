// An independent OPC UA client for ncgate's tests: node-opcua, driven by pytest
// (tests/integration/opcua/) through JSON lines.  Each line on stdin is a request
// {"id": n, "op": ..., ...}; each answer is a line {"id": n, "ok": ...} or {"id": n, "error": ...}.
// Subscriptions print their notifications as lines {"tag": ..., "value": ...} as they come,
// in the order the server sent them.
"use strict";
const readline = require("readline");
const {
    OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, DataType,
    TimestampsToReturn, ClientMonitoredItem, constructEventFilter, makeBrowsePath,
    UserTokenType, NodeClass, BrowseDirection,
} = require("node-opcua-client");
const {readCertificate} = require("node-opcua-crypto");
const fs = require("fs");

let client = null;
let session = null;
let subscription = null;
let namespaces = [];

function out(obj) {
    process.stdout.write(JSON.stringify(obj) + "\n");
}

function plain(value) {
    if (value === null || value === undefined) return null;
    if (typeof value === "bigint") return Number(value);
    if (Array.isArray(value) || ArrayBuffer.isView(value)) return Array.from(value, plain);
    if (value.text !== undefined && value.locale !== undefined) return value.text;  // LocalizedText
    if (value.namespace !== undefined && value.value !== undefined && value.identifierType !== undefined) {
        return value.toString();  // NodeId
    }
    if (typeof value === "object" && value.name !== undefined && value.namespaceIndex !== undefined) {
        return `${value.namespaceIndex}:${value.name}`;  // QualifiedName
    }
    return value;
}

// A node named by {"ns": uri, "id": number|string}, or a NodeId string.
function nodeId(spec) {
    if (typeof spec === "string") return spec;
    const ns = namespaces.indexOf(spec.ns);
    if (ns < 0) throw new Error(`namespace ${spec.ns} not on the server`);
    return typeof spec.id === "number" ? `ns=${ns};i=${spec.id}` : `ns=${ns};s=${spec.id}`;
}

// A browse path of [uri, name] pairs from Objects.
function browsePath(pairs) {
    return "/" + pairs.map(([uri, name]) => {
        const ns = namespaces.indexOf(uri);
        if (ns < 0) throw new Error(`namespace ${uri} not on the server`);
        return `${ns}:${name}`;
    }).join("/");
}

const ops = {
    async endpoints({url}) {
        const c = OPCUAClient.create({endpointMustExist: false, connectionStrategy: {maxRetry: 0}});
        await c.connect(url);
        const endpoints = await c.getEndpoints();
        await c.disconnect();
        return endpoints.map(e => ({
            url: e.endpointUrl, mode: MessageSecurityMode[e.securityMode],
            policy: e.securityPolicyUri,
            tokens: (e.userIdentityTokens || []).map(t => UserTokenType[t.tokenType]),
        }));
    },
    // certificate/key: an X.509 user identity; application: the client's own application
    // certificate {certificate, key, uri} for the secure channel (else node-opcua's own).
    async connect({url, user, password, mode, policy, certificate, key, application}) {
        client = OPCUAClient.create({
            endpointMustExist: false, connectionStrategy: {maxRetry: 0},
            securityMode: MessageSecurityMode[mode || "None"],
            securityPolicy: SecurityPolicy[policy || "None"],
            ...(application ? {certificateFile: application.certificate,
                               privateKeyFile: application.key,
                               applicationUri: application.uri} : {}),
        });
        await client.connect(url);
        const identity = certificate
            ? {type: UserTokenType.Certificate, certificateData: readCertificate(certificate),
               privateKey: fs.readFileSync(key, "utf8")}  // PrivateKeyPEM
            : user ? {type: UserTokenType.UserName, userName: user, password}
                   : {type: UserTokenType.Anonymous};
        session = await client.createSession(identity);
        const ns = await session.read({nodeId: "ns=0;i=2255", attributeId: AttributeIds.Value});
        namespaces = ns.value.value;
        return namespaces;
    },
    async translate({path}) {
        const result = await session.translateBrowsePath(makeBrowsePath("RootFolder", "/Objects" + browsePath(path)));
        if (!result.statusCode.isGood()) throw new Error(`${result.statusCode.name}: ${JSON.stringify(path)}`);
        return result.targets[0].targetId.toString();
    },
    async read({node, attribute}) {
        const dv = await session.read({nodeId: nodeId(node), attributeId: AttributeIds[attribute || "Value"]});
        if (!dv.statusCode.isGood()) throw new Error(dv.statusCode.name);
        return plain(dv.value.value);
    },
    // ref: only the references of that type (a NodeId string) and its subtypes.
    async browse({node, ref}) {
        const result = await session.browse({nodeId: nodeId(node), browseDirection: BrowseDirection.Forward,
                                             includeSubtypes: true, resultMask: 63,
                                             ...(ref ? {referenceTypeId: ref} : {})});
        return result.references.map(r => ({
            name: `${namespaces[r.browseName.namespaceIndex]}|${r.browseName.name}`,
            node: r.nodeId.toString(), type: r.typeDefinition.toString(),
            cls: NodeClass[r.nodeClass], ref: r.referenceTypeId.toString(),
        }));
    },
    // Every node reached from `from` by forward hierarchical references (HasComponent,
    // HasProperty, Organizes, HasSubtype, ...): the start nodes' children, and below them
    // only nodes outside namespace 0 and outside the namespaces `skip` names.  Variables
    // carry their DataType and ValueRank, enumerations (DataTypes) their values' names.
    async walk({from, skip}) {
        const skipped = new Set(["http://opcfoundation.org/UA/", ...(skip || [])]);
        const found = [];
        const seen = new Set();
        let level = from.map(nodeId);
        while (level.length) {
            const results = await session.browse(level.map(n => ({
                nodeId: n, browseDirection: BrowseDirection.Forward, includeSubtypes: true,
                referenceTypeId: "i=33", resultMask: 63})));  // HierarchicalReferences
            const next = [];
            results.forEach((result, i) => {
                for (const r of result.references || []) {
                    const target = r.nodeId.toString();
                    found.push({
                        parent: level[i], node: target, ref: r.referenceTypeId.toString(),
                        name: `${namespaces[r.browseName.namespaceIndex]}|${r.browseName.name}`,
                        cls: NodeClass[r.nodeClass], type: r.typeDefinition.toString(),
                        ns: namespaces[r.nodeId.namespace],
                    });
                    if (!seen.has(target) && !skipped.has(namespaces[r.nodeId.namespace])) {
                        seen.add(target);
                        next.push(target);
                    }
                }
            });
            level = next;
        }
        const variables = found.filter(f => f.cls === "Variable");
        for (let i = 0; i < variables.length; i += 500) {
            const chunk = variables.slice(i, i + 500);
            const reads = chunk.flatMap(v => [
                {nodeId: v.node, attributeId: AttributeIds.DataType},
                {nodeId: v.node, attributeId: AttributeIds.ValueRank}]);
            const values = await session.read(reads);
            chunk.forEach((v, j) => {
                v.datatype = values[2 * j].value.value.toString();
                v.rank = values[2 * j + 1].value.value;
            });
        }
        // An enumeration's names by value (its DataTypeDefinition's fields).
        for (const d of found.filter(f => f.cls === "DataType")) {
            const dv = await session.read({nodeId: d.node,
                                           attributeId: AttributeIds.DataTypeDefinition});
            const fields = dv.value.value && dv.value.value.fields;
            if (fields && fields.length && fields[0].value !== undefined) {
                const names = [];
                for (const f of fields) {  // an Int64: node-opcua's [high, low]
                    const v = Array.isArray(f.value) ? f.value[0] * 2 ** 32 + f.value[1]
                                                     : Number(f.value);
                    names[v] = f.name;
                }
                d.enum = Array.from(names, n => n === undefined ? "?" : n);
            }
        }
        return found;
    },
    async write({node, type, value}) {
        const code = await session.write({nodeId: nodeId(node), attributeId: AttributeIds.Value,
                                          value: {value: {dataType: DataType[type], value}}});
        return code.name;
    },
    async subscribe({interval}) {
        subscription = await session.createSubscription2({
            requestedPublishingInterval: interval || 50, requestedLifetimeCount: 1000,
            requestedMaxKeepAliveCount: 20, maxNotificationsPerPublish: 0,
            publishingEnabled: true, priority: 1,
        });
        return subscription.subscriptionId;
    },
    // A method call: its status code's name.  args: [[DataType name, value], ...]; a
    // ByteString is an array of bytes, a LocalizedText its text.
    async call({object, method, args}) {
        const result = await session.call({
            objectId: nodeId(object), methodId: nodeId(method),
            inputArguments: (args || []).map(([type, value]) => ({
                dataType: DataType[type],
                value: type === "ByteString" ? Buffer.from(value)
                     : type === "LocalizedText" ? {text: value} : value}))});
        return result.statusCode.name;
    },
    async monitor({tag, node, queue}) {
        const item = ClientMonitoredItem.create(subscription,
            {nodeId: nodeId(node), attributeId: AttributeIds.Value},
            {samplingInterval: 0, discardOldest: false, queueSize: queue || 1000},
            TimestampsToReturn.Both);
        item.on("changed", dv => out({tag, value: plain(dv.value.value)}));
        await new Promise((resolve, reject) => {
            item.once("initialized", resolve);
            item.once("err", reject);
        });
        return tag;
    },
    async events({tag, node, fields}) {
        const filter = constructEventFilter(fields.map(([uri, name]) => {
            const ns = uri ? namespaces.indexOf(uri) : 0;
            return ns ? `${ns}:${name}` : name;
        }));
        const item = ClientMonitoredItem.create(subscription,
            {nodeId: nodeId(node), attributeId: AttributeIds.EventNotifier},
            {samplingInterval: 0, discardOldest: false, queueSize: 1000, filter},
            TimestampsToReturn.Both);
        item.on("changed", values => out({tag, value: values.map(v => plain(v.value))}));
        await new Promise((resolve, reject) => {
            item.once("initialized", resolve);
            item.once("err", reject);
        });
        return item.monitoredItemId;  // (ConditionRefresh2 names it)
    },
    async close() {
        if (session) await session.close();
        if (client) await client.disconnect();
        session = client = null;
        return true;
    },
};

const lines = readline.createInterface({input: process.stdin});
let queue = Promise.resolve();
lines.on("line", line => {
    const request = JSON.parse(line);
    queue = queue.then(async () => {
        try {
            out({id: request.id, ok: await ops[request.op](request)});
        } catch (error) {
            out({id: request.id, error: String(error && error.message || error)});
        }
    });
});
lines.on("close", () => queue.then(() => ops.close()).finally(() => process.exit(0)));
